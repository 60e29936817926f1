"""The compiled CPU kernels: C++ sources beside their Python wrappers, built on first use."""
