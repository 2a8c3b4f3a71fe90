"""Bounds on the position error: the Cramér–Rao bounds of ToA and of the position (``crb``) and the misspecified bound of
a receiver that ignores the NLoS excess delay (``misspecified``)."""
