"""Synthetic scenes for tests, training and evaluation: ``render`` (boxes on a textured ground,
ray-cast through any rig) and ``streams`` (the seeded random streams drawn from it and their
files on disk).
"""
