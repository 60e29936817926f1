"""C++ source of the Gauss-Newton tracker's normal equations (built on first use by ``geometry.icp_native``)."""
