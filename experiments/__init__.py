"""ippc.experiments: studies that run the whole stack end to end.

`ippc.experiments.print_fetch` reproduces the paper's print-fetching robot
study in a simulated office (`make experiments`; docs/print-fetch.md).
"""
