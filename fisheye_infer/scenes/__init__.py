"""Synthetic scenes for tests, training and evaluation: ``scene`` (the boxes of a frame and their
look, drawn at random), ``render`` (a scene on a textured ground, ray-cast through any rig, and
whole frames written with their labels), ``streams`` (the seeded random streams drawn from
them and their files on disk) and ``sequences`` (one scene over time, its objects moving as
``actors`` simulates them, written with ids, velocities and ego poses for tracking).
"""
