# cffi_modules can only be declared through setup(); all metadata lives in pyproject.toml.
from setuptools import setup

setup(cffi_modules=["build_ffi.py:ffibuilder"])
