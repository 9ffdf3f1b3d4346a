"""A live ROS 2 node: camera topics in, ``vision_msgs/Detection3DArray`` and ``visualization_msgs/MarkerArray`` out.

    python examples/ros2_node.py model.onnx fisheye_camera_front=/front/image/compressed ...

A thin layer over what ``fisheye_infer.ros`` provides and tests (the message conversions and the
synchroniser): rclpy subscribes and publishes, nothing else. It needs a ROS 2 installation with
``vision_msgs`` (rclpy comes with ROS 2, not from the package registries) and the ``ros`` extra.
Messages cross between rclpy and ``rosbags`` as their CDR bytes (``rclpy.serialization``), so the node
runs the same code as ``fisheye-infer replay``.
"""

from __future__ import annotations

import sys

import rclpy
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import CompressedImage, Image
from vision_msgs.msg import Detection3DArray
from visualization_msgs.msg import MarkerArray

from fisheye_infer.ros.cdr import detection_array_cdr, marker_array_cdr
from fisheye_infer.ros.messages import ImageRefused, image_from_message, stamp_ns, typestore
from fisheye_infer.ros.sync import Synchroniser
from fisheye_infer.runtime.detector import Detector


class DetectorNode(Node):
    """Subscribes to one image topic per camera, runs the detector on each synchronised set, publishes."""

    def __init__(self, model: str, topics: dict[str, str], frame_id: str = "lidar") -> None:
        super().__init__("fisheye_infer")
        self.detector = Detector(model)
        self.frame_id = frame_id
        self.store = typestore()
        self.sync = Synchroniser(list(self.detector.info.cameras), tolerance_ns=20_000_000, queue_size=5)
        self.detections = self.create_publisher(Detection3DArray, "/detections", 10)
        self.markers = self.create_publisher(MarkerArray, "/detections/markers", 10)
        for camera, topic in topics.items():
            kind = CompressedImage if topic.endswith("compressed") else Image
            msgtype = f"sensor_msgs/msg/{kind.__name__}"
            self.create_subscription(kind, topic, lambda msg, c=camera, t=msgtype: self.on_image(c, t, msg), 5)

    def on_image(self, camera: str, msgtype: str, msg: object) -> None:
        converted = self.store.deserialize_cdr(serialize_message(msg), msgtype)
        for synced in self.sync.push(camera, stamp_ns(converted.header), converted):
            info = self.detector.info
            try:  # the service's checks: an image of another size or format is refused before decoding
                frame = {
                    c: image_from_message(m, c, size)
                    for c, size, m in zip(info.cameras, info.camera_sizes, synced.items, strict=True)
                }
            except ImageRefused as exc:
                self.get_logger().warning(f"frame at {synced.stamp} ns dropped ({exc.reason}): {exc}")
                continue
            detections = self.detector.detect(frame)
            array = detection_array_cdr(detections, synced.stamp, self.frame_id)
            markers = marker_array_cdr(detections, synced.stamp, self.frame_id)
            self.detections.publish(deserialize_message(array, Detection3DArray))
            self.markers.publish(deserialize_message(markers, MarkerArray))


def main(argv: list[str]) -> None:
    model, *pairs = argv
    rclpy.init()
    rclpy.spin(DetectorNode(model, dict(pair.split("=", 1) for pair in pairs)))


if __name__ == "__main__":
    main(sys.argv[1:])
