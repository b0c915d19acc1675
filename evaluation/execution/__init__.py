"""How a run's rollouts execute: the jobs, the passes over the samples, the executors (serial, processes, Ray)
with their worker preload and memory, the engine timing and the progress lines."""
