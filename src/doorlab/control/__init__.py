"""The control laws and the plans built on them: the problem set's pointwise IK, Jacobian
velocity mapping and Jacobian-transpose impedance, the one-shot IK, and the adaptive plan
with its hinge estimation.

A plan reads the arm's state and returns a command; it knows the cell's geometry, not how an
episode runs it.
"""
