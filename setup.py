"""What pyproject.toml cannot say: the compiled parts, and the examples as package data.

- The tap analysis's optional compiled kernels (src/tapcell/tap/c/). Each is a small C extension
  with a numpy twin in the Python module that calls it (tapcell.tap.native): an install without a
  C compiler still gets a working analysis, only slower, so the build of each is optional.
- The firmware host library (firmware/src + firmware/host), which the virtual printer loads through
  cffi (tapcell.mcu._lib). A checkout builds it with `make -C firmware host`; an installed wheel has
  no firmware/ folder, so the build puts it into the package as `tapcell/mcu/_firmware*.so`. It is
  built like an extension (the compiler setuptools finds) but has no Python entry point: cffi
  dlopens it. Optional too: `tapcell analyze` needs no firmware, and the virtual printer says how to
  get it when it is missing.
- The example configs (examples/*.cfg) go into the package as `tapcell/examples/`, so `tapcell init`,
  the console and the demo find them outside a checkout (tapcell.package_files).
"""

from pathlib import Path

from setuptools import Extension, setup
from setuptools.command.build_py import build_py

# No fused multiply-adds: the kernels repeat their numpy twins' arithmetic operation for operation
# (clang, and gcc outside strict ISO modes, would fuse a * b + c on FMA hardware such as a Pi's).
COMPILE_ARGS = ["-std=c99", "-O3", "-Wall", "-Wextra", "-fno-fast-math", "-ffp-contract=off"]
KERNELS = ("analysis", "segments", "contact", "toe", "stage", "ringing", "hum", "uncertainty", "readers", "output")
# As firmware/Makefile builds the host library, without -Werror: a compiler that warns differently
# must still build it on a user's machine (make firmware-check keeps the warnings out).
FIRMWARE_ARGS = ["-std=c99", "-O2", "-Wall", "-Wextra", "-ffp-contract=off"]


def firmware_library() -> Extension:
    sources = sorted(str(p) for p in (*Path("firmware/src").glob("*.c"), *Path("firmware/host").glob("*.c")))
    headers = sorted(str(p) for p in Path("firmware/include").glob("*.h"))
    # The Python host drives the library from one thread, with no interrupts: hal.h's critical
    # sections are no-ops there, as in firmware/Makefile's host build.
    return Extension("tapcell.mcu._firmware", sources, include_dirs=["firmware/include"], depends=headers,
                     define_macros=[("TC_SINGLE_THREADED", None)], extra_compile_args=FIRMWARE_ARGS,
                     optional=True)


class BuildPyWithExamples(build_py):
    """build_py, plus examples/*.cfg copied into the built package as tapcell/examples/."""

    def run(self):
        super().run()
        target = Path(self.build_lib, "tapcell", "examples")
        self.mkpath(str(target))
        for config in sorted(Path("examples").glob("*.cfg")):
            self.copy_file(str(config), str(target / config.name))


setup(ext_modules=[*(Extension(f"tapcell.tap._c_{name}", [f"src/tapcell/tap/c/{name}.c"],
                               depends=["src/tapcell/tap/c/buffers.h", "src/tapcell/tap/c/median.h", "src/tapcell/tap/c/fft.h",
                                        "src/tapcell/tap/c/sum.h", "src/tapcell/tap/c/clones.h"],
                               extra_compile_args=COMPILE_ARGS,
                               optional=True)
                     for name in KERNELS),
                   firmware_library()],
      cmdclass={"build_py": BuildPyWithExamples})
