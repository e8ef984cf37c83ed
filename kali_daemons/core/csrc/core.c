/* The kernels every library has: copies between arrays (kernels.copies).
 * Part of a library's one translation unit (controller.c, simulator.c), after common.h. */

/* ---------------------------------------------------------------- publish */

/* m flat arrays of n elements each into their records */
int64_t kali_copy(CopyArgs *a) {
    for (int64_t c = 0; c < a->m; c++) {
        Copy *k = &a->copies[c];
        for (int64_t i = 0; i < a->n; i++)
            memcpy(k->dst.p + i * k->dst.stride, k->src.p + i * k->src.stride, (size_t)k->size);
    }
    return 0;
}
