"""The paper's quantitative test: random samples, the trajectory cost and the reports."""
