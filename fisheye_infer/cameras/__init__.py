"""Cameras and rigs: how a pixel relates to a ray, and where each camera sits.

``camera_models`` (OCam, Kannala-Brandt, equidistant, pinhole behind one interface), ``ocam_fit``
(an OCam model fitted to a Kannala-Brandt calibration), ``rig`` (named cameras with poses),
``rig_files`` (the rig file formats read and written), ``carla_poses`` (CARLA sensor poses to
cam2lidar matrices).
"""
