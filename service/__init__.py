"""fisheye_infer.service"""
