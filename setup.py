# cffi_modules can only be declared through setup(); all metadata lives in pyproject.toml.
# build_py also compiles the Sparkplug B .proto (protoc, Debian's protobuf-compiler): the
# generated module matches the python3-protobuf it runs with, so it is never committed.
import subprocess

from setuptools import setup
from setuptools.command.build_py import build_py

PROTO_DIR = "mbgw/northbound"


class BuildWithProto(build_py):
    def run(self) -> None:
        subprocess.run(["protoc", f"--proto_path={PROTO_DIR}", f"--python_out={PROTO_DIR}",
                        f"--pyi_out={PROTO_DIR}", f"{PROTO_DIR}/sparkplug_b.proto"], check=True)
        super().run()


setup(cffi_modules=["build_ffi.py:ffibuilder"], cmdclass={"build_py": BuildWithProto})
