"""Storage layer for recording and replay: rosbag2 (Jazzy) MCAP bags, written and read
without a ROS graph (no node code here)."""
