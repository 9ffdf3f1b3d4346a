"""fisheye_infer.models.training: training FisheyeBEVDet on synthetic frames (needs the [export] extra).

    targets.py   Gaussian heatmap target and box code of the TransFusion head
    assign.py    3D IoU and the Hungarian assignment of proposals to ground truth
    losses.py    the official heatmap, classification and box losses
    depth.py     depth targets from the renderer and BEVDepth's depth loss (synthetic frames only)
    compact.py   the compact configuration and its mmdet3d-style config file
    options.py   the run's options, the learning-rate schedule and the training device
    batches.py   what each step trains on (seeded frames and depth targets), rendered ahead
    loop.py      optimiser, checkpoints, --resume, progress and log

The frames come from ``fisheye_infer.scenes.streams`` (seeded, randomised and torch-free, so a
held-out set is written and evaluated without torch). ``fisheye-infer train`` is
``fisheye_infer.commands.train`` (torch-free until it runs).
"""
