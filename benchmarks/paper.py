"""The paper's own figures ("Exploring Surround-View Fisheye Camera 3D Object Detection", AAAI 2026), by
registered architecture, for the tables that put ours beside them. CARLA scenes of Fisheye3DOD; every
model trained for 20 epochs per configuration (the layouts of Table 3 retrained per layout).
"""

from __future__ import annotations

#: The paper's name and cameras of each architecture's row.
METHOD = {
    "pinhole-bevdet": ("BEVDet", "6 x P"),
    "fisheye-bevdet-persp": ("BEVDet", "4 x F, perspective-rectified"),
    "fisheye-bevdet-cyl": ("BEVDet", "4 x F, cylindrically rectified"),
    "fisheye-bevdet": ("FisheyeBEVDet", "4 x F, equirectangular"),
    "pinhole-petr": ("PETR", "6 x P"),
    "fisheye-petr-persp": ("PETR", "4 x F, perspective-rectified"),
    "fisheye-petr-cyl": ("PETR", "4 x F, cylindrically rectified"),
    "fisheye-petr": ("FisheyePETR", "4 x F, equirectangular"),
}

#: Table 2 (RQ1/RQ2), 0-48 m: FDS, mAP, mATE, mASE, mAOE.
TABLE2 = {
    "pinhole-bevdet": (0.563, 0.506, 0.458, 0.161, 0.520),
    "fisheye-bevdet-persp": (0.440, 0.304, 0.588, 0.177, 0.505),
    "fisheye-bevdet-cyl": (0.453, 0.322, 0.591, 0.178, 0.478),
    "fisheye-bevdet": (0.485, 0.382, 0.591, 0.164, 0.480),
    "pinhole-petr": (0.553, 0.482, 0.580, 0.120, 0.430),
    "fisheye-petr-persp": (0.408, 0.274, 0.783, 0.161, 0.433),
    "fisheye-petr-cyl": (0.411, 0.285, 0.773, 0.169, 0.447),
    "fisheye-petr": (0.470, 0.374, 0.727, 0.142, 0.434),
}

#: Table 3 (RF1/RF2), 0-48 m: (FDS, mAP) by architecture and layout.
TABLE3 = {
    "pinhole-bevdet": {"without front and rear": (0.370, 0.206)},
    "fisheye-bevdet": {"front + rear": (0.454, 0.324), "left + right": (0.431, 0.315), "all": (0.485, 0.382)},
    "pinhole-petr": {"without front and rear": (0.321, 0.142)},
    "fisheye-petr": {"front + rear": (0.421, 0.289), "left + right": (0.382, 0.244), "all": (0.470, 0.374)},
}

#: Table 4 (RF3): (FDS, mAP) at 0-30 m and at 0-48 m.
TABLE4 = {
    "pinhole-bevdet": {"0-30 m": (0.673, 0.684), "0-48 m": (0.563, 0.506)},
    "fisheye-bevdet": {"0-30 m": (0.586, 0.555), "0-48 m": (0.485, 0.382)},
    "pinhole-petr": {"0-30 m": (0.652, 0.634), "0-48 m": (0.553, 0.482)},
    "fisheye-petr": {"0-30 m": (0.564, 0.516), "0-48 m": (0.470, 0.374)},
}
