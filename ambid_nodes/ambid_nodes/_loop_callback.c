/* ambid_nodes._loop_callback: a loop node's subscription callback, kernel and answer in compiled code.
 *
 * Per sample the lock-step loop is two messages, and each node answers each
 * message it takes with one of its own. A LoopCallback is the subscription's
 * callback (rclpy's executor calls it with the message's bytes): it runs the
 * node's compiled kernel (loop_kernels.py) and publishes the answer with rcl,
 * without a Python frame or rclpy's publish call. What the kernel leaves undone
 * goes to the node's Python handler.
 *
 * The kernel has the type of loop_call.LoopCall's and reads the words of its
 * context (loop_kernels.LOOP_*):
 *     context[LOOP_K]      the index k the message must carry, passed to the kernel
 *     context[LOOP_GATE]   0: every message goes to the handler (the node's Python path)
 *     context[LOOP_LIMIT]  the kernel runs only for k < limit
 *     context[LOOP_COUNT]  messages answered here (the node adds them to its tally)
 *     context[LOOP_OUT]    address and length of the bytes the kernel packs its answer into
 * A kernel returning LOOP_DONE (1) took the message and packed the answer, with
 * nothing else to do: k and count go up by 1 and the answer is published. Any
 * other code, or a closed gate (code NOT_RUN, -1), goes to handler(data, code).
 *
 *     LoopCallback(publisher, kernel, context, handler)
 *         publisher: the rcl_publisher_t address (rclpy's handle.pointer; the caller keeps
 *         the handle alive while the callback may run); kernel: the cfunc's address;
 *         context: a writable C-contiguous int64 buffer of at least N_LOOP words (held)
 *     callback(data)   data: bytes (or any C-contiguous buffer)
 *
 * Taking the next messages here too (the partner's answer is in this process's
 * reader as soon as the publish returns) ran the composed loop twice as fast,
 * but with rclpy 7.1's EventsExecutor and rmw_fastrtps it lost other readers'
 * notifications in the same process (service responses, other subscribers of
 * the loop topics), so every message still comes through the executor.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#include <rcl/error_handling.h>
#include <rcl/publisher.h>
#include <rcutils/allocator.h>

#define LOOP_K 0
#define LOOP_GATE 1
#define LOOP_LIMIT 2
#define LOOP_COUNT 3
#define LOOP_OUT 4
#define N_LOOP 6
#define LOOP_DONE 1
#define NOT_RUN (-1)

typedef int64_t (*loop_kernel)(const uint8_t *data, int64_t size, int64_t k, int64_t *context);

typedef struct {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    rcl_publisher_t *publisher;
    loop_kernel kernel;
    Py_buffer context;
    PyObject *handler;
} LoopCallback;

static PyObject *
LoopCallback_vectorcall(PyObject *obj, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    LoopCallback *self = (LoopCallback *)obj;
    if (PyVectorcall_NARGS(nargsf) != 1 || kwnames != NULL) {
        PyErr_SetString(PyExc_TypeError, "LoopCallback takes one positional argument: the message");
        return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(args[0], &view, PyBUF_C_CONTIGUOUS) < 0) {
        return NULL;
    }
    int64_t *c = (int64_t *)self->context.buf;
    int64_t k = c[LOOP_K];
    int64_t code = NOT_RUN;
    if (c[LOOP_GATE] && k < c[LOOP_LIMIT]) {
        code = self->kernel((const uint8_t *)view.buf, (int64_t)view.len, k, c);
    }
    PyBuffer_Release(&view);
    if (code != LOOP_DONE) {
        return PyObject_CallFunction(self->handler, "OL", args[0], (long long)code);
    }
    c[LOOP_K] = k + 1;
    c[LOOP_COUNT] += 1;
    rcl_serialized_message_t answer = {
        .buffer = (uint8_t *)(intptr_t)c[LOOP_OUT], .buffer_length = (size_t)c[LOOP_OUT + 1],
        .buffer_capacity = (size_t)c[LOOP_OUT + 1], .allocator = rcutils_get_default_allocator()};
    if (rcl_publish_serialized_message(self->publisher, &answer, NULL) != RCL_RET_OK) {
        PyErr_Format(PyExc_RuntimeError, "LoopCallback: publishing the answer to sample %lld failed: %s",
                     (long long)k, rcl_get_error_string().str);
        rcl_reset_error();
        return NULL;
    }
    Py_RETURN_NONE;
}

/* inspect.signature(callback) is (data, /): rclpy checks a subscription callback's signature */
static PyObject *
LoopCallback_get_signature(PyObject *Py_UNUSED(obj), void *Py_UNUSED(closure))
{
    PyObject *inspect = PyImport_ImportModule("inspect");
    if (inspect == NULL) {
        return NULL;
    }
    PyObject *result = NULL;
    PyObject *parameter_type = PyObject_GetAttrString(inspect, "Parameter");
    PyObject *kind = parameter_type ? PyObject_GetAttrString(parameter_type, "POSITIONAL_ONLY") : NULL;
    PyObject *parameter = kind ? PyObject_CallFunction(parameter_type, "sO", "data", kind) : NULL;
    if (parameter != NULL) {
        result = PyObject_CallMethod(inspect, "Signature", "([O])", parameter);
    }
    Py_XDECREF(parameter);
    Py_XDECREF(kind);
    Py_XDECREF(parameter_type);
    Py_DECREF(inspect);
    return result;
}

static PyObject *
LoopCallback_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"publisher", "kernel", "context", "handler", NULL};
    unsigned long long publisher, kernel;
    PyObject *context, *handler;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "KKOO", kwlist, &publisher, &kernel, &context, &handler)) {
        return NULL;
    }
    if (publisher == 0 || kernel == 0) {
        PyErr_SetString(PyExc_ValueError, "LoopCallback: the publisher or kernel address is 0");
        return NULL;
    }
    if (!PyCallable_Check(handler)) {
        PyErr_SetString(PyExc_TypeError, "LoopCallback: handler must be callable as handler(data, code)");
        return NULL;
    }
    LoopCallback *self = (LoopCallback *)type->tp_alloc(type, 0);
    if (self == NULL) {
        return NULL;
    }
    self->vectorcall = LoopCallback_vectorcall;
    if (PyObject_GetBuffer(context, &self->context, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        self->context.obj = NULL;
        Py_DECREF(self);
        return NULL;
    }
    if (self->context.itemsize != 8 || self->context.format == NULL
        || strchr("qlL", self->context.format[0]) == NULL || self->context.len < N_LOOP * 8) {
        PyErr_SetString(PyExc_ValueError, "LoopCallback: context must be an int64 buffer of at least 6 words");
        Py_DECREF(self);
        return NULL;
    }
    self->publisher = (rcl_publisher_t *)(uintptr_t)publisher;
    self->kernel = (loop_kernel)(uintptr_t)kernel;
    self->handler = Py_NewRef(handler);
    return (PyObject *)self;
}

static int
LoopCallback_traverse(PyObject *obj, visitproc visit, void *arg)
{
    LoopCallback *self = (LoopCallback *)obj;
    Py_VISIT(self->handler);
    Py_VISIT(self->context.obj);
    return 0;
}

static int
LoopCallback_clear(PyObject *obj)
{
    Py_CLEAR(((LoopCallback *)obj)->handler);
    return 0;
}

static void
LoopCallback_dealloc(PyObject *obj)
{
    LoopCallback *self = (LoopCallback *)obj;
    PyObject_GC_UnTrack(obj);
    Py_CLEAR(self->handler);
    if (self->context.obj != NULL) {
        PyBuffer_Release(&self->context);
    }
    Py_TYPE(obj)->tp_free(obj);
}

static PyGetSetDef LoopCallback_getset[] = {
    {"__signature__", LoopCallback_get_signature, NULL, "(data, /)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject LoopCallbackType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "ambid_nodes._loop_callback.LoopCallback",
    .tp_doc = "LoopCallback(publisher, kernel, context, handler): a loop node's subscription callback "
              "(see the module).",
    .tp_basicsize = sizeof(LoopCallback),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_VECTORCALL | Py_TPFLAGS_HAVE_GC,
    .tp_vectorcall_offset = offsetof(LoopCallback, vectorcall),
    .tp_call = PyVectorcall_Call,
    .tp_new = LoopCallback_new,
    .tp_dealloc = LoopCallback_dealloc,
    .tp_traverse = LoopCallback_traverse,
    .tp_clear = LoopCallback_clear,
    .tp_getset = LoopCallback_getset,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_loop_callback", "A loop node's subscription callback, kernel and answer in compiled code.",
    -1, NULL, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC
PyInit__loop_callback(void)
{
    if (PyType_Ready(&LoopCallbackType) < 0) {
        return NULL;
    }
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) {
        return NULL;
    }
    if (PyModule_AddObjectRef(m, "LoopCallback", (PyObject *)&LoopCallbackType) < 0
        || PyModule_AddIntConstant(m, "NOT_RUN", NOT_RUN) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
