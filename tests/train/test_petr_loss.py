"""FisheyePETR's training objective: the official box code, assignment and per-layer losses."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.models.petr_head import decode_predictions  # noqa: E402
from fisheye_infer.models.ranking import TopK  # noqa: E402
from fisheye_infer.models.training.assign import focal_cost  # noqa: E402
from fisheye_infer.models.training.losses import sigmoid_focal_loss  # noqa: E402
from fisheye_infer.models.training.petr_loss import (  # noqa: E402
    PETRLoss,
    PETRLossConfig,
    detr_assign,
    normalize_boxes,
)

K = 6


def _boxes(rng: np.random.Generator, n: int) -> np.ndarray:
    """Runtime boxes [x, y, z_bottom, l, w, h, yaw] with yaw anywhere in [-pi, pi)."""
    return np.column_stack(
        [
            rng.uniform(-40, 40, (n, 2)),
            rng.uniform(-2, 0, n),
            rng.uniform(0.5, 10, (n, 3)),
            rng.uniform(-np.pi, np.pi, n),
        ]
    )


class _Head:
    """What PETRLoss reads of a head: the class count."""

    class config:  # noqa: N801
        num_classes = K


def test_box_code_decodes_back_to_the_box() -> None:
    """normalize_boxes is the inverse of the head's decoding (layout, log sizes, gravity centre, yaw convention)."""
    boxes = _boxes(np.random.default_rng(0), 20)
    codes = torch.from_numpy(normalize_boxes(boxes)).float()[None]  # 1 x 20 x 8
    cls = torch.full((1, 20, K), -10.0)
    cls[0, torch.arange(20), 0] = torch.linspace(5, 1, 20)  # query i ranks i-th
    out = decode_predictions(cls, codes, TopK(20))
    decoded = out["boxes"][0].numpy()
    np.testing.assert_allclose(decoded[:, :6], boxes[:, :6], rtol=1e-5, atol=1e-4)
    yaw_error = np.angle(np.exp(1j * (decoded[:, 6] - boxes[:, 6])))
    np.testing.assert_allclose(yaw_error, 0, atol=1e-5)


def test_assignment_is_the_cheapest_one_to_one_match() -> None:
    rng = np.random.default_rng(1)
    cfg = PETRLossConfig()
    logits, codes = rng.normal(size=(5, K)), rng.normal(size=(5, 8)) * 3
    gt_codes, gt_labels = rng.normal(size=(3, 8)) * 3, np.array([0, 4, 4])
    index = detr_assign(logits, codes, gt_codes, gt_labels, cfg)
    cost = 2.0 * focal_cost(logits, gt_labels) + 0.25 * np.abs(codes[:, None] - gt_codes[None]).sum(-1)
    best = min(itertools.permutations(range(5), 3), key=lambda rows: sum(cost[r, g] for g, r in enumerate(rows)))
    assert sorted(index[index >= 0].tolist()) == [0, 1, 2]
    assert [int(np.nonzero(index == g)[0][0]) for g in range(3)] == list(best)
    assert detr_assign(logits, codes, np.zeros((0, 8)), np.zeros(0, np.int64), cfg).tolist() == [-1] * 5


def _perfect(boxes: np.ndarray, labels: np.ndarray, queries: int, layers: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Outputs whose first queries predict the boxes exactly, with confident classes; the others predict far off."""
    codes = torch.zeros(layers, 1, queries, 8)
    codes[..., 0] = 100.0
    codes[:, 0, : len(boxes)] = torch.from_numpy(normalize_boxes(boxes)).float()
    cls = torch.full((layers, 1, queries, K), -8.0)
    cls[:, 0, torch.arange(len(boxes)), torch.from_numpy(labels)] = 8.0
    return cls, codes


def test_perfect_predictions_cost_only_the_focal_floor() -> None:
    boxes, labels = _boxes(np.random.default_rng(2), 4), np.array([0, 1, 2, 5])
    cls, codes = _perfect(boxes, labels, queries=10, layers=3)
    terms = PETRLoss(_Head)(cls, codes, [boxes], [labels])
    assert float(terms["loss_bbox"]) == pytest.approx(0.0, abs=1e-5)
    assert float(terms["matched_error"]) == pytest.approx(0.0, abs=1e-4)
    # each layer's focal loss of the same outputs, weight 2, over 4 positives
    target = torch.full((10,), K, dtype=torch.int64)
    target[:4] = torch.from_numpy(labels)
    one = 2.0 * float(sigmoid_focal_loss(cls[0, 0], target)) / 4
    assert float(terms["loss_cls"]) == pytest.approx(3 * one, rel=1e-5)


def test_box_loss_is_weighted_l1_over_positives_summed_over_layers() -> None:
    boxes, labels = _boxes(np.random.default_rng(3), 2), np.array([1, 3])
    cls, codes = _perfect(boxes, labels, queries=6, layers=2)
    codes[1, 0, 0, 0] += 0.4  # the last layer's first match is 0.4 m off in x
    terms = PETRLoss(_Head)(cls, codes, [boxes], [labels])
    assert float(terms["loss_bbox"]) == pytest.approx(0.25 * 0.4 / 2, rel=1e-4)
    assert float(terms["matched_error"]) == pytest.approx(0.2, rel=1e-4)  # mean of 0.4 and 0


def test_frames_without_boxes_train_every_query_as_background() -> None:
    cls = torch.zeros(2, 1, 5, K, requires_grad=True)
    codes = torch.zeros(2, 1, 5, 8, requires_grad=True)
    terms = PETRLoss(_Head)(cls, codes, [np.zeros((0, 7))], [np.zeros(0, np.int64)])
    terms["loss"].backward()
    assert float(terms["loss_bbox"].detach()) == 0.0 and float(terms["loss_cls"].detach()) > 0
    assert cls.grad is not None and float(cls.grad.abs().sum()) > 0


def test_mismatched_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="ground truth for 2 frames"):
        PETRLoss(_Head)(torch.zeros(1, 1, 4, K), torch.zeros(1, 1, 4, 8), [np.zeros((0, 7))] * 2, [np.zeros(0)] * 2)
    with pytest.raises(ValueError, match="expected cls"):
        PETRLoss(_Head)(torch.zeros(1, 4, K), torch.zeros(1, 4, 8), [np.zeros((0, 7))], [np.zeros(0)])


@pytest.fixture(scope="module")
def small_petr():
    from small_configs import small_configs

    from fisheye_infer.models import create_model
    from fisheye_infer.models.training.objectives import PETRObjective

    config, rig = small_configs()["fisheye-petr"]
    model = create_model("fisheye-petr", config, rig)
    PETRObjective(model).init(seed=0)
    return model


def test_trainable_positions_equal_the_cached_embeddings(small_petr) -> None:
    """The torch path training uses computes the numbers the numpy geometry bakes for inference."""
    head = small_petr.pts_bbox_head
    key_pos, query_pos = head.trainable_positions()
    scale = float(head.key_pos.abs().max())
    torch.testing.assert_close(key_pos.detach(), head.key_pos, rtol=0, atol=1e-5 * scale)
    torch.testing.assert_close(query_pos.detach(), head.query_pos, rtol=0, atol=1e-6)


def test_training_reaches_every_embedding_weight(small_petr) -> None:
    head = small_petr.pts_bbox_head
    small_petr.zero_grad()
    key_pos, query_pos = head.trainable_positions()
    (key_pos.square().mean() + query_pos.square().mean()).backward()
    for name in ("position_encoder", "adapt_pos3d", "query_embedding", "reference_points"):
        grads = [p.grad for p in head.get_submodule(name).parameters()]
        assert all(g is not None and float(g.abs().sum()) > 0 for g in grads), name


def test_init_sets_the_official_priors(small_petr) -> None:
    from fisheye_infer.models.training.objectives import CLASS_PRIOR

    head = small_petr.pts_bbox_head
    assert torch.all(head.cls_branches[-1][-1].bias == CLASS_PRIOR)
    assert float(torch.sigmoid(torch.tensor(CLASS_PRIOR))) == pytest.approx(0.01)
    ref = head.reference_points.weight.detach()
    assert float(ref.min()) >= 0 and float(ref.max()) <= 1 and float(ref.std()) > 0.2  # uniform in [0, 1]


def test_init_leaves_the_first_cross_attention_unsaturated(small_petr, monkeypatch: pytest.MonkeyPatch) -> None:
    """At the official initialisation each query spreads its first cross-attention over many keys; with the
    synthetic checkpoints' fan-in weights the softmax puts nearly all of it on one key (mean maximum 0.9 on the
    compact model) and training stalls with every query alike."""
    from fisheye_infer.models import petr_transformer

    head = small_petr.pts_bbox_head
    keys = int(head.key_pos.shape[1])
    softmax, largest = torch.softmax, []

    def spy(x: torch.Tensor, dim: int = -1, **kwargs) -> torch.Tensor:
        weights = softmax(x, dim=dim, **kwargs)
        if x.shape[-1] == keys:
            largest.append(float(weights.max(-1).values.mean()))
        return weights

    monkeypatch.setattr(petr_transformer.torch, "softmax", spy)
    size = (1, 4, small_petr.config.image.height, small_petr.config.image.width, 3)
    images = torch.randint(0, 256, size, dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        head.forward_decoder(small_petr.image_features(images))
    assert largest and largest[0] < 0.2, largest
