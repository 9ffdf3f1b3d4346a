"""Cameras and rigs: how a pixel relates to a ray, and where each camera sits.

``camera_models`` (OCam, Kannala-Brandt, equidistant, pinhole, distorted pinhole, double sphere,
EUCM and Mei's omnidirectional model behind one interface), ``ocam_fit`` (an OCam model fitted to
another model's calibration), ``rig`` (named cameras with poses), ``rig_files`` (the rig file
formats read and written), ``calibration_files`` (Kalibr, ROS CameraInfo and OpenCV calibrations
read into camera models), ``carla_poses`` (CARLA sensor poses to cam2lidar matrices).
"""
