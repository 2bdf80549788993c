"""Planar positioning compensation: seed 000's grid model (``paper``) and our own (``lattice``)."""
