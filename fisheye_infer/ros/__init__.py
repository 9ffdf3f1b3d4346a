"""ROS 2 glue (the ``ros`` extra: ``rosbags``, ``mcap``, the Foxglove schemas): camera messages to frames,
detections to ``vision_msgs`` and Foxglove messages, a camera synchroniser, and bag replay to MCAP.

``messages`` (ROS 2 messages in and out), ``sync`` (approximate-time synchronisation of N cameras),
``foxglove`` (3D boxes and per-camera overlays drawn through each camera's own model), ``replay``
(a recorded bag through a ``Detector`` into an MCAP file and nuScenes-style records).
"""
