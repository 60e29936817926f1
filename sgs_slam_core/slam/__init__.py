"""The SLAM loop: tracking, densification, keyframes, mapping, and the ``Slam`` facade.

Import the facade from :mod:`sgs_slam_core.slam.system` (or ``sgs_slam_core.Slam``); this package
module stays import-free so the config schema can use :mod:`sgs_slam_core.slam.settings`.
"""
