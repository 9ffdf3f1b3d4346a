"""fisheye_infer.models"""
