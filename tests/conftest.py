"""Suite-wide test settings. Per-area fixtures live in tests/<area>/conftest.py."""

import os

# CPU only, and quiet about optional GPU back ends; set before jax is imported.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
