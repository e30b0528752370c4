"""The ROS layer: messages and their CDR bytes, topic names and types, frame names, the URDF,
the IMU's readings, trajectory goals as joint_trajectory_controller reads them, the live view."""
