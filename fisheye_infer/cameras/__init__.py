"""Cameras and rigs: how a pixel relates to a ray, and where each camera sits.

``camera_models`` (OCam, Kannala-Brandt, equidistant, pinhole, distorted pinhole, double sphere,
EUCM and Mei's omnidirectional model behind one interface: ``camera_model_base``, ``ocam_model``,
``kannala_brandt``, ``pinhole_models``, ``unified_models``, ``radtan_distortion`` behind it),
``ocam_fit`` (an OCam model fitted to another model's calibration), ``rig`` (named cameras with
poses; ``rig_camera`` one camera, ``rig_construction`` and ``rig_inspection`` what its methods do,
``default_rigs`` the shipped rigs and ``resolve_rig``), ``rig_files`` (the rig file formats read and
written), ``calibration_files`` (Kalibr, ROS CameraInfo, OpenCV and OCamCalib calibrations read into
camera models; ``kalibr_camchain`` and ``calibration_values`` behind it), ``field_of_view`` (what an
image shows and what a model projects), ``text_input`` (files from outside read with bounds),
``carla_poses`` (CARLA sensor poses to cam2lidar matrices).
"""
