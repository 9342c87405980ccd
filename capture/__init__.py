"""Reading stereo recordings (EuRoC/ASL, ROS bags, left/right folders); pairing frames."""
