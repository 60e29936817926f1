"""C++ source of the fused photometric loss (built on first use by ``slam.photometric``)."""
