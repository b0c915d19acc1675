#!/usr/bin/env bash
# The reference against every contestant on sample sets it was not built on (docs/optimality.md,
# "The reference on held-out samples"). Each run: HJB cost with Q = 4·I, no effort matching, every
# controller at its own settings (lqr at q_scale 1: the frozen-Jacobian optimum of the run's own cost),
# so that the contestants come as close to the optimum as they can. Writes runs/holdout/<set>/.
# Usage: bash docs/scripts/reference_holdout.sh [SAMPLES]   (default 50 per task and set)
set -euo pipefail
n=${1:-50}
out=runs/holdout
all=(--controllers snac,snac-hjb,snac-adaptive,lqr,mpc,rnn,svf,dls,ppo,pink,mink,optimal)
common=(--samples "$n" --workers 2 --cost hjb --q-scale 4 --no-match-effort --no-progress --no-plots)
all+=(--param lqr.q_scale=1)
mkdir -p "$out"
# Samples of our own outside Table I's ranges: workspace draws of seed 13 whose target or ellipse centre
# lies outside the UR10 cuboid, ellipses up to 0.4 rad/s (the cuboid's are 0.075 rad/s).
snac-gym evaluate --out "$out/export13" --sample-space workspace --seed 13 --samples 200 \
  --export-samples "$out/outside.csv" --export-only
python docs/scripts/outside_cuboid.py "$out/outside.csv" "$n"
snac-gym evaluate --out "$out/default" "${all[@]}" "${common[@]}"
for seed in 11 12; do
  snac-gym evaluate --out "$out/workspace$seed" --sample-space workspace --seed "$seed" "${all[@]}" "${common[@]}"
done
for robot in panda xarm7; do  # the shipped PPO policies are the UR arms' (6 joints)
  snac-gym evaluate --out "$out/$robot" --robot "$robot" "${all[@]/ppo,/}" "${common[@]}"
done
snac-gym evaluate --out "$out/outside" --samples-file "$out/outside.csv" "${all[@]}" "${common[@]:2}"
# The velocity-only variant of the reference on the same sets: the rollouts that cross a joint limit are
# counted apart, and must not be below it.
for set in default workspace11 workspace12 panda xarm7; do
  case $set in
    workspace*) extra=(--sample-space workspace --seed "${set#workspace}") ;;
    panda|xarm7) extra=(--robot "$set") ;;
    *) extra=() ;;
  esac
  snac-gym evaluate --out "$out/$set-velocity" --controllers optimal --reference-limits velocity "${extra[@]}" "${common[@]}"
done
snac-gym evaluate --out "$out/outside-velocity" --samples-file "$out/outside.csv" --controllers optimal \
  --reference-limits velocity "${common[@]:2}"
