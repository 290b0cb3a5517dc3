"""shinro_ctrl.codegen: compiled CasADi functions, their disk cache and the virtual-machine fallback.

Each test compiles a tiny expression into its own tmp folder (a few hundred ms of gcc in all); the reference value of
every compiled function is the same expression evaluated by CasADi's virtual machine.
"""

from __future__ import annotations

import os
import stat
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import casadi as cs
import numpy as np
import pytest

from shinro_ctrl.codegen import (
    DEFAULT_FLAGS,
    CompilerUnavailable,
    compiled,
    compiled_by_key,
    default_flags,
    find_compiler,
)


def _fun(name: str = "cg_f", power: float = 3.0) -> cs.Function:
    x = cs.SX.sym("x", 2)
    return cs.Function(name, [x], [cs.vertcat(cs.sin(x[0]) * x[1] ** power, x[0] * x[1] + 1)], ["x"], ["y"])


def _libraries(folder: Path) -> list[Path]:
    return sorted(folder.rglob("*.so"))


def _script(path: Path, body: str) -> str:
    """An executable shell script at ``path`` (a stand-in compiler)."""
    path.write_text("#!/bin/sh\n" + body)
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return str(path)


X = np.array([0.7, -1.3])


def test_a_compiled_function_equals_the_vm_and_a_second_request_loads_the_cached_library(tmp_path, monkeypatch):
    cc = tmp_path / "cc"  # the compiler is part of the key: the same name, working first, failing later
    monkeypatch.setenv("CC", _script(cc, f'exec {find_compiler()} "$@"\n'))
    f = _fun()
    c = compiled(f, folder=tmp_path)
    assert c.is_a("External")  # machine code, not the SX virtual machine
    np.testing.assert_allclose(np.asarray(c(X)), np.asarray(f(X)), rtol=1e-15, atol=0)
    (lib,) = _libraries(tmp_path)
    mtime = lib.stat().st_mtime_ns
    # a cache hit runs no compiler: with a compiler that always fails, the library still loads, silently
    _script(cc, "exit 1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        again = compiled(f, folder=tmp_path)
    assert again.is_a("External")
    assert _libraries(tmp_path) == [lib] and lib.stat().st_mtime_ns == mtime
    np.testing.assert_allclose(np.asarray(again(X)), np.asarray(f(X)), rtol=1e-15, atol=0)


def test_a_changed_expression_under_the_same_name_gets_a_new_library(tmp_path):
    a, b = _fun(power=3.0), _fun(power=2.0)
    ca, cb = compiled(a, folder=tmp_path), compiled(b, folder=tmp_path)
    assert len(_libraries(tmp_path)) == 2
    np.testing.assert_allclose(np.asarray(ca(X)), np.asarray(a(X)), rtol=1e-15, atol=0)
    np.testing.assert_allclose(np.asarray(cb(X)), np.asarray(b(X)), rtol=1e-15, atol=0)
    assert not np.allclose(np.asarray(ca(X)), np.asarray(cb(X)))


def test_compiled_by_key_builds_on_a_miss_only_and_a_new_key_rebuilds(tmp_path):
    calls: list[float] = []

    def build(power: float):
        def make() -> cs.Function:
            calls.append(power)
            return _fun("cg_keyed", power)

        return make

    first = compiled_by_key("cg_keyed", "model A", build(3.0), folder=tmp_path)
    assert calls == [3.0] and first.is_a("External")
    hit = compiled_by_key("cg_keyed", "model A", build(99.0), folder=tmp_path)  # the key decides: no build
    assert calls == [3.0]
    np.testing.assert_allclose(np.asarray(hit(X)), np.asarray(_fun(power=3.0)(X)), rtol=1e-15, atol=0)
    other = compiled_by_key("cg_keyed", "model B", build(2.0), folder=tmp_path)
    assert calls == [3.0, 2.0] and len(_libraries(tmp_path)) == 2
    np.testing.assert_allclose(np.asarray(other(X)), np.asarray(_fun(power=2.0)(X)), rtol=1e-15, atol=0)


def test_without_a_compiler_the_vm_evaluates_it_with_one_warning(tmp_path, monkeypatch):
    monkeypatch.setenv("CC", str(tmp_path / "nonexistent"))
    f = _fun()
    with pytest.warns(CompilerUnavailable) as record:
        out = compiled(f, folder=tmp_path)
        keyed = compiled_by_key("cg_f", "k", _fun, folder=tmp_path)
        compiled(_fun(power=2.0), folder=tmp_path)
    assert len(record) == 1  # once per reason, not once per function
    (line,) = str(record[0].message).splitlines()
    assert "nonexistent" in line and "virtual machine" in line
    assert out is f and not keyed.is_a("External")
    np.testing.assert_allclose(np.asarray(keyed(X)), np.asarray(f(X)), rtol=1e-15, atol=0)
    assert _libraries(tmp_path) == []


def test_a_compiler_that_fails_gives_the_vm_and_its_first_error_line(tmp_path, monkeypatch):
    cc = _script(tmp_path / "broken_cc", 'echo "broken_cc: fatal error: cannot build $*" >&2\necho more >&2\nexit 1\n')
    monkeypatch.setenv("CC", cc)
    f = _fun("cg_broken")
    with pytest.warns(CompilerUnavailable, match="could not build cg_broken .broken_cc: fatal error") as record:
        out = compiled(f, folder=tmp_path)
    assert out is f and len(record) == 1 and "\n" not in str(record[0].message)
    assert _libraries(tmp_path) == []  # nothing half-built left behind
    # real gcc refusing a bad flag: the same fallback
    monkeypatch.delenv("CC")
    with pytest.warns(CompilerUnavailable, match="could not build cg_flag"):
        bad = compiled(_fun("cg_flag"), flags=["-fno-such-option-shinro"], folder=tmp_path)
    assert not bad.is_a("External")


def test_two_processes_building_the_same_function_compile_once_and_both_load_it(tmp_path):
    log = tmp_path / "cc.log"
    real = find_compiler()
    cc = _script(tmp_path / "logging_cc", f'echo "$$" >> "{log}"\nsleep 0.3\nexec {real} "$@"\n')
    child = textwrap.dedent(
        f"""
        import casadi as cs, numpy as np
        from shinro_ctrl.codegen import compiled_by_key
        def build():
            x = cs.SX.sym("x", 2)
            return cs.Function("cg_race", [x], [cs.vertcat(cs.sin(x[0]) * x[1] ** 3, x[0] * x[1] + 1)])
        f = compiled_by_key("cg_race", "race", build, folder={str(tmp_path / "cache")!r})
        assert f.is_a("External"), "fell back to the VM"
        print(float(f([0.7, -1.3])[0]))
        """
    )
    env = {**os.environ, "CC": cc, "PYTHONPATH": os.pathsep.join(sys.path)}
    procs = [subprocess.Popen([sys.executable, "-c", child], env=env, stdout=subprocess.PIPE, text=True) for _ in "ab"]
    outs = [p.communicate(timeout=120)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0]
    expected = float(np.sin(0.7) * (-1.3) ** 3)
    values = [float(o) for o in outs]
    assert values[0] == values[1]
    np.testing.assert_allclose(values[0], expected, rtol=1e-15)
    assert len(_libraries(tmp_path / "cache")) == 1
    assert len(log.read_text().split()) == 1  # the second process waited on the lock and loaded the first's library


def test_flags_from_the_environment_are_part_of_the_key(tmp_path, monkeypatch):
    f = _fun("cg_env")
    monkeypatch.setenv("SHINRO_CTRL_CFLAGS", "-O0 -g0")
    assert default_flags() == ("-O0", "-g0")
    low = compiled(f, folder=tmp_path)
    monkeypatch.setenv("SHINRO_CTRL_CFLAGS", "-O1")
    high = compiled(f, folder=tmp_path)
    assert len(_libraries(tmp_path)) == 2  # one library per set of flags, never mixed up
    np.testing.assert_array_equal(np.asarray(low(X)), np.asarray(high(X)))  # the same arithmetic
    monkeypatch.delenv("SHINRO_CTRL_CFLAGS")
    assert default_flags() == DEFAULT_FLAGS
