"""The paper's print-fetching robot study in a simulated office.

`office` holds the map, the rates and the four experiments (and generates
the RDDL instances in domains/print_fetch/).
"""
