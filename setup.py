"""The tap analysis's optional compiled kernels (src/tapcell/tap/c/).

Everything else about the package is in pyproject.toml. Each kernel is a small C extension with a
numpy twin in the Python module that calls it (tapcell.tap.native): an install without a C
compiler still gets a working analysis, only slower, so the build of each is optional.
"""

from setuptools import Extension, setup

# No fused multiply-adds: the kernels repeat their numpy twins' arithmetic operation for operation
# (clang, and gcc outside strict ISO modes, would fuse a * b + c on FMA hardware such as a Pi's).
COMPILE_ARGS = ["-std=c99", "-O3", "-Wall", "-Wextra", "-fno-fast-math", "-ffp-contract=off"]
KERNELS = ("analysis", "segments", "contact", "toe", "readers")

setup(ext_modules=[Extension(f"tapcell.tap._c_{name}", [f"src/tapcell/tap/c/{name}.c"],
                             depends=["src/tapcell/tap/c/buffers.h", "src/tapcell/tap/c/median.h"],
                             extra_compile_args=COMPILE_ARGS,
                             optional=True)
                   for name in KERNELS])
