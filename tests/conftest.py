import gc
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
    # (and later runs on this machine reuse it). It never stores a program with a host
    # callback: a test's own jit around a solve with throw=True (the default) compiles in
    # every run. A cache the user set is left alone.
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


def _mapping_budget():
    # Half of what Linux allows a process (`vm.max_map_count`); None off Linux.
    try:
        with open("/proc/sys/vm/max_map_count") as f:
            return int(f.read()) // 2
    except (OSError, ValueError):
        return None


_MAPPING_BUDGET = _mapping_budget()


def _mappings():
    with open("/proc/self/maps") as f:
        return sum(1 for _ in f)


@pytest.fixture(scope="module", autouse=True)
def _release_compiled_programs():
    # Each XLA CPU executable holds about twenty memory mappings while it lives, and a
    # worker keeps every program it compiled: at about 88% of the suite a worker reached
    # Linux's 65 530 mappings, a compilation failed, and jaxlib crashed the worker while
    # raising the error (a segmentation fault in the unwinder; the worker's core held 65 293
    # mappings). Past half the limit, the programs of the modules already run are dropped.
    yield
    if _MAPPING_BUDGET is not None and _mappings() > _MAPPING_BUDGET:
        import nivpjax

        nivpjax.clear_caches()
        gc.collect()
