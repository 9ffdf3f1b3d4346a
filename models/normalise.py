"""Image normalisation as the graph runs it: the mean subtracted on channels-last rows.

Both detectors take uint8 B x N x H x W x 3 frames and feed ``(x - mean[c]) / std[c]``
channels-first to the first convolution. The exporter folds the division into that
convolution's weights (``fisheye_infer.export.graph.fold_input_scale``); the subtraction cannot
be folded, because the convolution's zero padding would then stand for ``mean`` instead of 0.

Where the subtraction runs decides its cost in ONNX Runtime. On channels-first planes it is
cheap; but an int8 file runs its first convolution channels-last, the layout optimiser moves a
channels-first Sub after the transposition, and a three-value constant broadcast over the last
axis runs element by element there (~5x slower than over planes). Subtracting the mean tiled
along a row, ``(W * 3,)``, over rows of ``W * 3`` values is fast in both layouts and gives the
same numbers: each element is the same float subtraction. The cast comes first, so that no UINT8
tensor is moved inside the fp32 graph (TensorRT takes UINT8 only at the network's edge).
"""

from __future__ import annotations

import torch

__all__ = ["normalise_frames"]


def normalise_frames(
    images: torch.Tensor, mean: torch.Tensor, std: torch.Tensor, bgr_to_rgb: bool = False
) -> torch.Tensor:
    """uint8 B x N x H x W x 3 -> float32 (B*N) x 3 x H x W, ``(x - mean[c]) / std[c]``.

    ``mean`` and ``std``: 3 values, in the order of the output channels. ``bgr_to_rgb`` swaps the
    first and last input channels before the statistics apply (the frames are BGR, as cv2 decodes).
    """
    b, n, h, w, c = images.shape
    mean, std = mean.reshape(c), std.reshape(c)
    if bgr_to_rgb:  # subtract in the input's channel order, swap the planes afterwards
        mean = mean.flip(0)
    rows = images.to(torch.float32).reshape(b * n, h, w * c) - mean.repeat(w)
    x = rows.reshape(b * n, h, w, c).permute(0, 3, 1, 2)
    if bgr_to_rgb:
        x = x.flip(1)
    return x / std.reshape(1, c, 1, 1)
