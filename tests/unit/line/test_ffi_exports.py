"""The built C core exports its module entry point and nothing else (-fvisibility=hidden)."""
import shutil
import subprocess

import pytest

from mbgw import _ffi


def exported_symbols(path: str) -> set[str]:
    out = subprocess.run(["nm", "-D", "--defined-only", path], check=True,
                         capture_output=True, text=True).stdout
    return {line.split()[-1] for line in out.splitlines() if line.strip()}


@pytest.mark.skipif(shutil.which("nm") is None, reason="needs nm (binutils)")
def test_the_c_core_exports_only_its_entry_point_and_mbgw_functions():
    symbols = exported_symbols(_ffi.__file__)
    assert "PyInit__ffi" in symbols
    stray = sorted(s for s in symbols if s != "PyInit__ffi" and not s.startswith("mbgw_"))
    assert stray == [], f"{_ffi.__file__} exports internal symbols: {stray}"
