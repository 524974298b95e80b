/* The segments kernels of the tap analysis (numpy twins: tapcell/tap/segments.py). */
#include "buffers.h"

static PyMethodDef methods[] = {
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_c_segments", "The segments kernels of the tap analysis.", -1,
                                    methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__c_segments(void) { return PyModule_Create(&module); }
