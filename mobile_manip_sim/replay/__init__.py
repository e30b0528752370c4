"""`replay`: a recorded bag played back onto ROS topics (`play`), or re-simulated from the bag
alone and compared with it (`resimulate`); `cli` is the command. What a bag of ours holds is
read through `recording.bag_format`."""
