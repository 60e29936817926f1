"""C++ sources of the compiled CPU backend (built on first use by ``render.cpu_backend``)."""
