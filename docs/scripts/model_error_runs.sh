#!/usr/bin/env bash
# The model-error table of docs/model-error.md and the README: 100 + 100 samples per error, the HJB cost with
# Q = 4·I, every controller at its own settings except lqr, which gets the critics' weights (q_scale 1).
#   bash docs/scripts/model_error_runs.sh [SEED] [OUT]      then: python docs/scripts/model_error_table.py ...
set -euo pipefail
seed=${1:-41}
out=${2:-runs}
controllers=snac,snac-hjb,snac-adaptive,lqr,rnn,svf,dls,optimal
declare -A errors=(
  [none]=""
  [ur5]="model=ur5"
  [random0]="random=0.005,0"
  [random1]="random=0.005,1"
  [random2]="random=0.005,2"
  [combined]="joint_offset=0,0.3,0.5,0,0.3,0;link_scale=-0.1;tool_offset=0.05,0.05,0.07"
)
for name in none ur5 random0 random1 random2 combined; do
  spec=${errors[$name]}
  args=(--out "$out/me_${name}_s$seed" --samples 100 --seed "$seed" --workers 2 --no-match-effort --cost hjb
        --q-scale 4 --controllers "$controllers" --param lqr.q_scale=1 --no-plots --no-progress)
  [ -n "$spec" ] && args+=(--model-error "$spec")
  start=$(date +%s)
  snac-gym evaluate "${args[@]}" > "$out/me_${name}_s$seed.log"
  echo "$name: $(( $(date +%s) - start )) s"
done
