"""JAX's compilation cache for the command line (``adaptive_cal/cli/jax_cache.py``): where it
lives, that it is used only in a folder private to the user (JAX calls its entries trusted
code), that it can be turned off or pointed elsewhere, and that a later process loads what an
earlier one compiled."""
import os
import subprocess
import sys

import pytest

from adaptive_cal.cli import jax_cache

KEYS = ("JAX_COMPILATION_CACHE_DIR", "ADAPTIVE_CAL_JAX_CACHE", "XDG_CACHE_HOME",
        "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "JAX_COMPILATION_CACHE_MAX_SIZE")


@pytest.fixture
def clean_env(monkeypatch):
    """No cache setting from the test run itself (conftest points the tests at a shared one);
    JAX's loaded config is left as it is."""
    for key in KEYS:
        monkeypatch.delenv(key, raising=False)
    monkeypatch.setitem(sys.modules, "jax", None)  # enable() sees no loaded JAX
    return monkeypatch


def test_the_default_folder_is_created_private_under_the_xdg_cache(clean_env, tmp_path):
    clean_env.setenv("XDG_CACHE_HOME", str(tmp_path))
    got = jax_cache.enable()
    folder = tmp_path / "adaptive-cal" / "jax"
    assert got == str(folder) and folder.is_dir()
    assert folder.stat().st_mode & 0o777 == 0o700
    assert os.environ["JAX_COMPILATION_CACHE_DIR"] == str(folder)
    assert os.environ["JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"] == "0"
    assert int(os.environ["JAX_COMPILATION_CACHE_MAX_SIZE"]) == jax_cache.MAX_BYTES


@pytest.mark.parametrize("word", ["off", "0", "OFF", "none"])
def test_it_can_be_turned_off(clean_env, tmp_path, word):
    clean_env.setenv("XDG_CACHE_HOME", str(tmp_path))
    clean_env.setenv("ADAPTIVE_CAL_JAX_CACHE", word)
    assert jax_cache.enable() is None
    assert "JAX_COMPILATION_CACHE_DIR" not in os.environ
    assert not (tmp_path / "adaptive-cal").exists()


def test_a_folder_others_may_write_to_is_not_used(clean_env, tmp_path):
    shared = tmp_path / "shared"
    shared.mkdir()
    shared.chmod(0o777)
    clean_env.setenv("ADAPTIVE_CAL_JAX_CACHE", str(shared))
    assert jax_cache.enable() is None
    assert "JAX_COMPILATION_CACHE_DIR" not in os.environ


def test_the_users_own_jax_setting_is_kept(clean_env, tmp_path):
    clean_env.setenv("JAX_COMPILATION_CACHE_DIR", str(tmp_path / "mine"))
    clean_env.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert jax_cache.enable() == str(tmp_path / "mine")
    assert not (tmp_path / "xdg").exists()


def test_a_later_process_loads_what_an_earlier_one_compiled(tmp_path):
    """Two processes compile the same program: the first writes entries, the second adds none
    and gets the same numbers."""
    env = {k: v for k, v in os.environ.items() if k not in KEYS}
    env["XDG_CACHE_HOME"] = str(tmp_path)
    code = ("from adaptive_cal.cli import jax_cache; print(jax_cache.enable()); import jax; "
            "jax.config.update('jax_enable_x64', True); import jax.numpy as jnp; "
            "f = jax.jit(lambda a: jnp.linalg.cholesky(a @ a.T + 3 * jnp.eye(4)).sum()); "
            "print(repr(float(f(jnp.arange(16.0).reshape(4, 4) / 7))))")
    folder = tmp_path / "adaptive-cal" / "jax"
    runs, written = [], []
    for _ in range(2):
        runs.append(subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                                   text=True, timeout=120))
        written.append(sorted(p.name for p in folder.glob("*-cache")))
    for r in runs:
        assert r.returncode == 0, r.stderr
        assert r.stdout.splitlines()[0] == str(folder)
        assert "cache" not in r.stderr.lower(), r.stderr  # no warning about the cache
    assert runs[0].stdout == runs[1].stdout
    assert any(name.startswith("jit__lambda") for name in written[0]), written[0]
    assert written[1] == written[0]  # the second compiled nothing new: it loaded
