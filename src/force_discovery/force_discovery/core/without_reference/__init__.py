"""Discovery without a reference: a campaign without the stationary cell or the encoder, or with fewer pulls than
the analysis with a reference needs (identifiability picks the path). The method is driver.py's docstring; the
modules are listed in force_discovery.core's. ROS-free."""
