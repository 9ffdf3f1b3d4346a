"""fisheye_infer.models.training: training FisheyeBEVDet, FisheyePETR and the baselines of the paper's Table 2
on synthetic frames (needs the [export] extra).

    targets.py   Gaussian heatmap target and box code of the TransFusion head
    assign.py    3D IoU and the Hungarian assignment of proposals to ground truth
    losses.py    FisheyeBEVDet's official heatmap, classification and box losses
    petr_loss.py FisheyePETR's official box code, per-layer assignment and losses
    depth.py     depth targets of any LSS lift from the renderer and BEVDepth's depth loss (synthetic frames)
    objectives.py what a step minimises and how the weights start, per architecture
    compact.py   the compact configurations and the rigs they train on: the table of trainable architectures
    trainable.py the trainable architectures' names, and which of them a configuration or config file is
    config_file.py  the mmdet3d-style config file of a run
    options.py   the run's options, the learning-rate schedule and the training device
    batches.py   what each step trains on (seeded frames and depth targets), rendered ahead
    run_checkpoints.py  a run's checkpoints written atomically, its saved options, --init and --init-backbone checks
    progress.py  the progress line
    loop.py      the trainer: optimiser, steps, validation, checkpoints, --resume and log

The frames come from ``fisheye_infer.scenes.streams`` (seeded, randomised and torch-free, so a
held-out set is written and evaluated without torch). ``fisheye-infer train`` is
``fisheye_infer.commands.train`` (torch-free until it runs).
"""
