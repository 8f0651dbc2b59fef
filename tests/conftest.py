import getpass
import os
import tempfile

import jax
import jax.random as jr
import pytest


os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_dtype_promotion", "standard")


def _share_compiled_programs():
    # XLA compilation dominates the suite's time, and many tests compile programs another
    # test (or the other xdist worker) has already compiled: closures rebuilt per test give
    # the same XLA program, which JAX's in-memory caches, keyed by function identity, miss.
    # JAX's persistent cache is keyed by the program itself: the workers share one on disk
    # (and later runs on this machine reuse it). A cache the user set is left alone.
    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return
    try:
        user = "".join(c for c in getpass.getuser() if c.isalnum()) or "user"
    except (KeyError, OSError):  # no name for this uid (some containers)
        user = str(os.getuid()) if hasattr(os, "getuid") else "user"
    path = os.path.join(tempfile.gettempdir(), f"nivpjax-tests-jax-cache-{user}")
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)


_share_compiled_programs()


def pytest_configure(config):
    # Under `-n 2` (the README's command), whole files go to a worker (`--dist loadfile`)
    # rather than single tests: a file's tests share their compiled programs (module-level
    # fixtures, the solve cache), which a split across workers compiles twice.
    if getattr(config.option, "dist", "no") == "load":
        config.option.dist = "loadfile"


@pytest.fixture
def getkey():
    key = [jr.PRNGKey(0)]

    def _getkey():
        key[0], sub = jr.split(key[0])
        return sub

    return _getkey
