"""Builds mbgw._ffi: cffi out-of-line API mode, csrc/*.c linked against Debian's libmodbus."""
import glob
import re
import shlex
import subprocess

from cffi import FFI

# The part of libmodbus 3.1.6 that the Python side calls or reads, and no more.
LIBMODBUS_CDEF = """
typedef struct _modbus modbus_t;
modbus_t *modbus_new_rtu(const char *device, int baud, char parity, int data_bit, int stop_bit);
int modbus_connect(modbus_t *ctx);
void modbus_close(modbus_t *ctx);
void modbus_free(modbus_t *ctx);
int modbus_get_socket(modbus_t *ctx);
int modbus_send_raw_request(modbus_t *ctx, const uint8_t *raw_req, int raw_req_length);
#define EMBBADCRC ...
#define EMBBADDATA ...
"""


def _pkg_config(flag: str, fallback: list[str]) -> list[str]:
    try:
        out = subprocess.run(["pkg-config", flag, "libmodbus"], check=True,
                             capture_output=True, text=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return fallback
    return shlex.split(out)


def _our_cdef() -> str:
    with open("csrc/mbgw.h") as header:
        text = header.read()
    # cffi fills in the values of #defines itself in API mode.
    return re.sub(r"^#define (\w+) .*$", r"#define \1 ...", text, flags=re.M)


include_dirs = [f[2:] for f in _pkg_config("--cflags-only-I", ["-I/usr/include/modbus"])]

ffibuilder = FFI()
ffibuilder.cdef(LIBMODBUS_CDEF + _our_cdef())
ffibuilder.set_source(
    "mbgw._ffi",
    '#include <modbus.h>\n#include "mbgw.h"\n',
    sources=sorted(glob.glob("csrc/*.c")),
    include_dirs=["csrc", *include_dirs],
    libraries=["modbus"],
    # Hidden by default: the extension exports PyInit__ffi (cffi marks it) and nothing else,
    # so csrc's unprefixed internal helpers (be16, read_some, ...) clash with no other library.
    extra_compile_args=["-std=gnu99", "-O2", "-fvisibility=hidden",
                        "-Wall", "-Wextra", "-Werror"],
)

if __name__ == "__main__":
    ffibuilder.compile(verbose=True)
