"""The SLAM loop: tracking, densification, keyframes, mapping, and the ``Slam`` facade (``sgs_slam_core.Slam``)."""
