"""Deployment beyond one process: ``ray_batch`` (Ray Data batch inference over frames on disk) and
``triton`` (the exported file behind NVIDIA Triton Inference Server).
"""
