/* ambid_nodes._loop_call: call a compiled per-sample kernel for the cost of a C call.
 *
 * The lock-step loop nodes run one compiled kernel per message (loop_kernels.py).
 * Through numba's own entry point a call costs 1-4 us, most of it unboxing each
 * array argument into a reference-counted meminfo and releasing it again under
 * the GIL state API; the arithmetic takes ~0.4 us. A LoopCall holds the kernel's
 * address and a context vector (int64 words: buffer addresses and sizes the
 * kernel reads), so a call passes only the message and the sample index.
 *
 *     LoopCall(address, context)   address: int, a numba cfunc of the type
 *                                  int64 (const uint8 *data, int64 size, int64 k, int64 *context)
 *                                  context: a writable C-contiguous int64 buffer (held while
 *                                  the LoopCall lives)
 *     call(data, k) -> int         data: bytes (or any buffer), k: int
 *
 * The kernel trusts the addresses in its context: the Python side that writes
 * them keeps the buffers alive (loop_call.py).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

typedef int64_t (*loop_kernel)(const uint8_t *data, int64_t size, int64_t k, int64_t *context);

typedef struct {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    loop_kernel kernel;
    Py_buffer context;
} LoopCall;

static PyObject *
LoopCall_vectorcall(PyObject *obj, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    LoopCall *self = (LoopCall *)obj;
    if (PyVectorcall_NARGS(nargsf) != 2 || kwnames != NULL) {
        PyErr_SetString(PyExc_TypeError, "LoopCall takes exactly two positional arguments: (data, k)");
        return NULL;
    }
    long long k = PyLong_AsLongLong(args[1]);
    if (k == -1 && PyErr_Occurred()) {
        return NULL;
    }
    PyObject *data = args[0];
    if (PyBytes_CheckExact(data)) {  /* what a raw subscription hands over: no buffer export needed */
        return PyLong_FromLongLong(self->kernel((const uint8_t *)PyBytes_AS_STRING(data),
                                                PyBytes_GET_SIZE(data), k, self->context.buf));
    }
    Py_buffer view;
    if (PyObject_GetBuffer(data, &view, PyBUF_C_CONTIGUOUS) < 0) {
        return NULL;
    }
    int64_t code = self->kernel((const uint8_t *)view.buf, view.len, k, self->context.buf);
    PyBuffer_Release(&view);
    return PyLong_FromLongLong(code);
}

static PyObject *
LoopCall_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"address", "context", NULL};
    unsigned long long address;
    PyObject *context;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "KO", kwlist, &address, &context)) {
        return NULL;
    }
    if (address == 0) {
        PyErr_SetString(PyExc_ValueError, "LoopCall: the kernel address is 0");
        return NULL;
    }
    LoopCall *self = (LoopCall *)type->tp_alloc(type, 0);
    if (self == NULL) {
        return NULL;
    }
    if (PyObject_GetBuffer(context, &self->context, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        self->context.obj = NULL;
        Py_DECREF(self);
        return NULL;
    }
    if (self->context.itemsize != 8 || self->context.format == NULL
        || (strcmp(self->context.format, "l") != 0 && strcmp(self->context.format, "q") != 0)) {
        PyErr_SetString(PyExc_TypeError, "LoopCall: the context must be an int64 buffer (numpy int64 array)");
        Py_DECREF(self);
        return NULL;
    }
    self->kernel = (loop_kernel)(uintptr_t)address;
    self->vectorcall = LoopCall_vectorcall;
    return (PyObject *)self;
}

static void
LoopCall_dealloc(LoopCall *self)
{
    if (self->context.obj != NULL) {
        PyBuffer_Release(&self->context);
    }
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static PyTypeObject LoopCallType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "ambid_nodes._loop_call.LoopCall",
    .tp_doc = PyDoc_STR("LoopCall(address, context): call(data, k) -> int runs the kernel at address"),
    .tp_basicsize = sizeof(LoopCall),
    .tp_new = LoopCall_new,
    .tp_dealloc = (destructor)LoopCall_dealloc,
    .tp_call = PyVectorcall_Call,
    .tp_vectorcall_offset = offsetof(LoopCall, vectorcall),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_VECTORCALL,
};

static struct PyModuleDef loop_call_module = {
    PyModuleDef_HEAD_INIT, "_loop_call", "Call a compiled per-sample kernel for the cost of a C call.", -1, NULL,
};

PyMODINIT_FUNC
PyInit__loop_call(void)
{
    if (PyType_Ready(&LoopCallType) < 0) {
        return NULL;
    }
    PyObject *module = PyModule_Create(&loop_call_module);
    if (module == NULL) {
        return NULL;
    }
    Py_INCREF(&LoopCallType);
    if (PyModule_AddObject(module, "LoopCall", (PyObject *)&LoopCallType) < 0) {
        Py_DECREF(&LoopCallType);
        Py_DECREF(module);
        return NULL;
    }
    return module;
}
