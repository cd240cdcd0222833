"""The simulated manipulation station of the problem set (runs on doorlab)."""
