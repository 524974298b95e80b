/* A loop function built twice where the compiler and C library can (gcc 6+ or clang 14+, x86-64,
 * glibc's ifuncs): with AVX2 (four doubles at once) and without (two, SSE2), the one the CPU runs
 * chosen when the module loads. The same IEEE operations either way (no fused multiply-adds:
 * -ffp-contract=off), so the same values bit for bit. Mark a function `static ROW_LOOP`. */
#ifndef TAPCELL_CLONES_H
#define TAPCELL_CLONES_H

#if defined(__x86_64__) && defined(__GLIBC__) && \
    ((defined(__clang__) && __clang_major__ >= 14) || (!defined(__clang__) && defined(__GNUC__) && __GNUC__ >= 6))
#define ROW_LOOP __attribute__((target_clones("avx2", "default")))
#else
#define ROW_LOOP
#endif

#endif
