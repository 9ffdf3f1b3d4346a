"""Box utilities, NMS and the Detections value type, on hand-built boxes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import FrameError
from fisheye_infer.runtime.box_geometry import bev_corners, corners, project_boxes
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.nms import NmsConfig, apply_nms, bev_iou, circle_nms, rotated_bev_nms

CLASSES = ("Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist")


def box(
    x: float, y: float, l: float = 4.0, w: float = 2.0, yaw: float = 0.0, z: float = -1.5, h: float = 1.5
) -> list[float]:
    return [x, y, z, l, w, h, yaw]


class TestCorners:
    def test_axis_aligned(self) -> None:
        c = corners(np.array([box(10.0, 2.0)]))[0]
        np.testing.assert_allclose(c[:4, :2], [[12, 3], [12, 1], [8, 1], [8, 3]])
        np.testing.assert_allclose(c[:4, 2], -1.5)
        np.testing.assert_allclose(c[4:, 2], 0.0)

    def test_yaw_turns_counter_clockwise(self) -> None:
        """yaw = +90 degrees: the box's length runs along +y (left)."""
        c = bev_corners(np.array([box(0.0, 0.0, yaw=math.pi / 2)]))[0]
        np.testing.assert_allclose(c[0], [-1.0, 2.0], atol=1e-12)  # front-left corner: ahead along +y, left is -x

    def test_shape_is_checked(self) -> None:
        with pytest.raises(ValueError, match=r"expected shape \(K, 7\)"):
            corners(np.zeros((3, 6)))


class TestIou:
    @pytest.mark.parametrize(
        ("a", "b", "expected"),
        [
            (box(0, 0), box(0, 0), 1.0),
            (box(0, 0), box(2, 0), 4.0 / 12.0),  # half overlap along x: 2x2 of two 4x2
            (box(0, 0), box(10, 0), 0.0),
            (
                box(0, 0, l=2, w=2),
                box(0, 0, l=2, w=2, yaw=math.pi / 4),
                (8 * (math.sqrt(2) - 1)) / (8 - 8 * (math.sqrt(2) - 1)),
            ),
            # two 4x1 boxes at yaw +30 degrees, the second 2 m further along their common length axis:
            # half of each overlaps, IoU 1/3 only if yaw turns counter-clockwise as the boxes' layout says
            (box(0, 0, l=4, w=1, yaw=math.pi / 6), box(math.sqrt(3), 1.0, l=4, w=1, yaw=math.pi / 6), 1.0 / 3.0),
            (box(0, 0, l=4, w=1, yaw=math.pi / 6), box(math.sqrt(3), -1.0, l=4, w=1, yaw=math.pi / 6), 0.0),
        ],
        ids=["identical", "half-overlap", "apart", "rotated-square", "rotated-along-length", "rotated-mirrored"],
    )
    def test_bev_iou(self, a, b, expected: float) -> None:
        assert bev_iou(np.array(a), np.array(b)) == pytest.approx(expected, abs=1e-4)


class TestNms:
    boxes = np.array([box(0, 0), box(0.5, 0.1), box(0, 0, yaw=0.05), box(20, 0), box(0.2, 0)], np.float32)
    scores = np.array([0.9, 0.8, 0.7, 0.6, 0.95], np.float32)
    labels = np.array([0, 0, 1, 0, 4])

    def test_rotated_class_aware(self) -> None:
        keep = rotated_bev_nms(self.boxes, self.scores, self.labels, iou=0.2)
        assert keep.tolist() == [4, 0, 2, 3]  # box 1 overlaps box 0 (same class); classes differ for 2 and 4

    def test_rotated_class_agnostic(self) -> None:
        keep = rotated_bev_nms(self.boxes, self.scores, self.labels, iou=0.2, class_aware=False)
        assert keep.tolist() == [4, 3]

    def test_per_class_threshold(self) -> None:
        keep = rotated_bev_nms(self.boxes, self.scores, self.labels, iou=0.2, per_class={0: 0.9})
        assert 1 in keep.tolist()

    def test_circle(self) -> None:
        keep = circle_nms(self.boxes, self.scores, self.labels, radius=1.0)
        assert keep.tolist() == [4, 0, 2, 3]
        assert circle_nms(self.boxes, self.scores, self.labels, radius=0.1).tolist() == [4, 0, 1, 2, 3]

    def test_config_by_class_name(self) -> None:
        keep = apply_nms(
            self.boxes, self.scores, self.labels, NmsConfig(kind="circle", radius=1.0, per_class={"Car": 0.1}), CLASSES
        )
        assert sorted(keep.tolist()) == [0, 1, 2, 3, 4]
        with pytest.raises(ValueError, match="unknown class"):
            apply_nms(self.boxes, self.scores, self.labels, NmsConfig(per_class={"Tram": 0.1}), CLASSES)

    @pytest.mark.parametrize(
        ("kwargs", "words"),
        [
            ({"per_class": {"Car": 0.0}}, r"per_class\['Car'\]: expected an IoU in \(0, 1\], got 0.0"),
            ({"per_class": {"Car": 1.5}}, r"per_class\['Car'\]: expected an IoU in \(0, 1\], got 1.5"),
            ({"kind": "circle", "per_class": {"Bus": -2.0}}, r"per_class\['Bus'\]: expected a radius > 0"),
            ({"iou": 0.0}, "iou"),
        ],
    )
    def test_config_refuses_thresholds_that_suppress_everything(self, kwargs: dict, words: str) -> None:
        with pytest.raises(ValueError, match=words):
            NmsConfig(**kwargs)


class TestDetections:
    dets = Detections(
        np.array([box(5, 0), box(40, 0), box(-3, 4)], np.float32),
        np.array([0.9, 0.2, 0.5], np.float32),
        np.array([0, 3, 4], np.int64),
        CLASSES,
        cameras_used=("front",),
    )

    def test_filters(self) -> None:
        assert self.dets.filter(min_score=0.3).names == ["Car", "Pedestrian"]
        assert self.dets.filter(classes=["Bus"]).names == ["Bus"]
        assert self.dets.filter(max_range=10.0).names == ["Car", "Pedestrian"]
        with pytest.raises(ValueError, match="unknown"):
            self.dets.filter(classes=["Tram"])

    def test_fields_are_validated(self) -> None:
        with pytest.raises(ValueError, match=r"scores: expected shape \(3,\)"):
            Detections(self.dets.boxes, np.zeros(2, np.float32), self.dets.labels, CLASSES)
        with pytest.raises(ValueError, match="labels: expected values in"):
            Detections(self.dets.boxes, self.dets.scores, np.array([0, 1, 6]), CLASSES)

    def test_json_round_trip(self) -> None:
        back = Detections.from_json(self.dets.to_json(), CLASSES)
        np.testing.assert_allclose(back.boxes, self.dets.boxes)
        assert back.names == self.dets.names and back.cameras_used == ("front",)
        np.testing.assert_allclose(back.scores, self.dets.scores)

    @pytest.mark.parametrize(
        "edit, message",
        [
            (lambda rows: rows[1].update(class_name="Tram"), r"detections\[1\]: class_name 'Tram' is not one of Car"),
            (lambda rows: rows[2].pop("yaw"), r"detections\[2\]: missing yaw"),
            (lambda rows: rows[0].update(x="far"), "box fields must be numbers"),
        ],
    )
    def test_bad_saved_rows_are_named(self, edit, message: str) -> None:
        import json

        doc = json.loads(self.dets.to_json())
        edit(doc["detections"])
        with pytest.raises(FrameError, match=message):
            Detections.from_json(json.dumps(doc), CLASSES)

    def test_corners_and_indexing(self) -> None:
        assert self.dets.corners().shape == (3, 8, 3)
        assert len(self.dets[np.array([True, False, True])]) == 2 and len(self.dets[1]) == 1
        assert len(Detections.empty(CLASSES)) == 0


def test_box_ahead_projects_into_the_front_camera_only_where_visible(rig: Rig) -> None:
    lines = project_boxes(np.array([box(8.0, 0.0)]), rig)
    front = lines["fisheye_camera_front"][0]
    assert len(front) >= 12
    pts = np.concatenate(front)
    model = rig.shared_model()
    assert np.all((pts >= 0) & (pts <= model.width - 1))
    assert abs(pts[:, 0].mean() - model.center_col) < 40  # straight ahead: around the image centre
    # the rear camera sees nothing of a box 8 m ahead, occluded by nothing but out of its 220-degree fov
    assert lines["fisheye_camera_rear"][0] == []


def test_projected_edges_stay_inside_each_cameras_valid_area(rig: Rig) -> None:
    """Boxes all around the car: every drawn point lies in the lens's valid area (its fov ellipse,
    2 px of rasterisation slack), and edges that leave it are cut, not drawn through."""
    import cv2

    boxes = np.array([box(x, y, yaw=0.3) for x in (-15.0, -4.0, 0.0, 4.0, 15.0) for y in (-10.0, -3.0, 3.0, 10.0)])
    lines = project_boxes(boxes, rig, samples_per_edge=16)
    model = rig.shared_model()
    area = cv2.dilate(model.valid_area(), np.ones((5, 5), np.uint8))
    drawn = [line for per_box in lines.values() for polylines in per_box for line in polylines]
    assert drawn
    for line in drawn:
        pixels = np.round(line).astype(int)
        assert area[pixels[:, 1], pixels[:, 0]].all()
    assert any(len(line) < 16 for line in drawn)  # some edges leave a camera's view and are cut there
