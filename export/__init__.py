"""fisheye_infer.export"""
