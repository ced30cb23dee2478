"""ROS-free core of force_discovery: what the model of record gets wrong in measured data."""
