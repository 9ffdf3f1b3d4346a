"""The runtime's data path: an exported file and encoded frames in, ``Detections`` out.

``artifact`` (the metadata an exported file carries; ``artifact_reports`` its parity, quantization,
TensorRT and virtual-camera records) -> ``session`` (ONNX Runtime) -> ``codec`` and ``preprocess``
(bytes to the graph's inputs) -> ``detector`` (``Detector``; ``frame_detector`` the frame handling it
shares with ``TritonDetector``, ``detector_interface`` the graph's interface checks and ``DetectorInfo``) ->
``detections``, ``nms``, ``options`` (boxes, filters, detect options) -> ``records`` (the result
records shared with results files and the evaluator). ``box_geometry`` holds the box corners,
footprints and their projection through a camera model.
"""
