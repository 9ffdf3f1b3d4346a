"""fisheye_infer.export: checkpoint -> one verified, self-contained ONNX file; re-baking for a new rig.

``export`` needs the ``[export]`` extra (torch, onnx); ``rebake`` needs only ``onnx``.
"""
