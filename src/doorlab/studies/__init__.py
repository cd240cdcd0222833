"""Studies across runs: the four controllers against the cupboard's yaw error, the original
station's figures doorlab is measured against, and the former episode design kept to measure
the current one.
"""
