"""The self-check's replays of a ranking: what the head computed before its ranking step is reused, and a
replay that reuses it gives the numbers of one that runs the whole head again."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from small_configs import small_configs  # noqa: E402

from fisheye_infer.export.frames import verification_frames  # noqa: E402
from fisheye_infer.export.ranking_replay import RankingHead  # noqa: E402
from fisheye_infer.models import load_model, make_checkpoint  # noqa: E402
from fisheye_infer.models.ranking import replay_ranking  # noqa: E402

#: What the replays reuse: PETR ranks after its decoder, TransFusion ranks its heatmap before the decoder.
REUSED = {"fisheye-petr": "transformer", "fisheye-bevdet": "heatmap_head"}


@pytest.mark.parametrize("arch", sorted(REUSED))
def test_a_replay_that_reuses_the_pre_ranking_outputs_is_a_full_replay(arch: str) -> None:
    config, rig = small_configs()[arch]
    model, _ = load_model(arch, make_checkpoint(arch, seed=3, config=config, rig=rig), config=config, rig=rig)
    model = model.double()
    frames = verification_frames(rig, 1, seed=5)
    head = RankingHead(model, frames, np.ones(frames.shape[:2], dtype=bool))
    reused = head.before_ranking[0].outputs
    assert REUSED[arch] in reused and not any(name.startswith(f"{REUSED[arch]}.") for name in reused)

    own = head.outputs[0]["rank_scores"][0]
    other = own + np.random.default_rng(0).normal(0.0, 1e-3, own.shape)  # another ranking
    k = head.outputs[0]["rank_indices"].shape[1]
    chosen = np.argsort(-other, kind="stable")[:k]
    assert not np.array_equal(chosen, head.outputs[0]["rank_indices"][0])

    fast = head.replay(0, other, chosen)
    args, kwargs = head.inputs[0]
    with (
        torch.no_grad(),
        replay_ranking(head.module, torch.from_numpy(other[None]), torch.from_numpy(chosen[None])) as step,
    ):
        full = head.module(*args, **kwargs)
    assert fast.problem == step.problem  # TransFusion ranks local maxima only: there this choice is no top-k
    for name, value in fast.out.items():
        np.testing.assert_array_equal(value, full[name].numpy(), err_msg=name)
    # the reused outputs are copies: a second replay is the first again
    again = head.replay(0, other, chosen)
    for name, value in fast.out.items():
        np.testing.assert_array_equal(value, again.out[name], err_msg=name)
