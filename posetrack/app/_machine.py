"""What a benchmark number was measured on: CPU, cores, JAX, XLA settings."""

from __future__ import annotations

import os
import platform


def machine_info() -> dict[str, object]:
    """CPU model, core count, JAX/jaxlib/NumPy/Python versions, backend, the first device's kind
    (``"cpu"``, ``"NVIDIA H200"``, ...) and XLA/thread settings."""
    import jax
    import numpy as np

    model = platform.processor() or platform.machine() or "unknown"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    model = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        import jaxlib

        jaxlib_version = jaxlib.__version__
    except (ImportError, AttributeError):
        jaxlib_version = "?"
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "jax": jax.__version__,
        "jaxlib": jaxlib_version,
        "backend": jax.default_backend(),
        "device": jax.devices()[0].device_kind,
        "XLA_FLAGS": os.environ.get("XLA_FLAGS", ""),
        "threads": {
            k: os.environ[k]
            for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
            if k in os.environ
        },
        "numpy": np.__version__,
        "python": platform.python_version(),
    }


def machine_summary() -> str:
    """One line: ``AMD EPYC, 2 cores, jax 0.10.2 (cpu), XLA_FLAGS=''``."""
    m = machine_info()
    backend = m["backend"] if m["backend"] == "cpu" else f"{m['backend']}: {m['device']}"
    return (
        f"{m['cpu']}, {m['cores']} cores, jax {m['jax']} ({backend}), "
        f"XLA_FLAGS='{m['XLA_FLAGS']}'"
    )
