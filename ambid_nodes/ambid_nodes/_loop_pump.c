/* ambid_nodes._loop_pump: take, step and answer the lock-step loop's messages in compiled code.
 *
 * Per sample the loop is two messages: the plant's y[k] and the controller's
 * answer. Through rclpy each costs an executor dispatch, a Python callback and
 * a publish call, several times the work of the compiled kernels
 * (loop_kernels.py). A Pump runs the loop nodes' kernels on the messages
 * itself: given a message for one of its entries, it runs that entry's kernel,
 * publishes the answer with rcl, and then takes the next message from any
 * entry's subscription with rcl directly, until none is waiting or it has
 * taken `budget` messages. Composed in one process, Fast DDS hands a message
 * to a subscription of the same process during the publish call, so the plant
 * and controller answer each other without leaving this loop; as separate
 * processes each process's pump takes its one message and returns.
 *
 * It runs on the executor's thread, inside the subscription callback: nothing
 * else of the node runs meanwhile (no locks, no second thread). The executor
 * still gets an event per message, and those for the messages the pump took
 * find nothing to take and call nothing. After `budget` messages the pump
 * takes every message then waiting (two, with a pipelined controller), holds
 * them and calls the first one's entry's kick() (unless a kick is already on
 * its way: each would start a run of its own), which makes the executor
 * call entry.resume() after the events queued so far: timers, services and
 * other subscribers (of the loop topics too) get their turn, in order. A
 * message left waiting instead would be taken by the first of those stale
 * events, restarting the pump ahead of everything else queued; the events
 * would pile up without bound and the other subscribers would lose messages.
 * A subscriber of the loop topics in the same process gets up to budget / 2
 * messages per turn: its queue must be at least that deep (qos.LOOP: 100).
 *
 * An entry's kernel has the type of loop_call.LoopCall's and reads the words
 * of its context (loop_kernels.LOOP_*):
 *     context[LOOP_K]      the index k the next message must carry, passed to the kernel
 *     context[LOOP_GATE]   0: every message goes to the node's handler (the node's Python path)
 *     context[LOOP_LIMIT]  the kernel runs only for k < limit
 *     context[LOOP_COUNT]  messages the pump took all the way (added to the node's tally)
 *     context[LOOP_OUT]    address and length of the bytes the kernel packs the answer into
 * A kernel returning LOOP_DONE (1) took the message and packed the answer with
 * nothing else to do: the pump adds 1 to k and count and publishes the answer.
 * Any other code, or a closed gate (code NOT_RUN, -1), goes to the entry's
 * handler(data: bytes, code: int) on this thread, which does the rest in Python.
 *
 *     Pump(budget)
 *     pump.add(subscription, publisher, kernel, context, handler, kick) -> Entry
 *         subscription, publisher: rcl_subscription_t / rcl_publisher_t addresses (rclpy's
 *         handle.pointer; the caller keeps the handles alive until entry.close())
 *         kernel: address of the cfunc; context: writable C-contiguous int64 buffer
 *     entry(data)     the subscription's callback: run the pump from this message
 *     entry.resume()  run the pump from the messages it holds, if any
 *     entry.close()   remove it from the pump (idempotent; drops messages held for it)
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <stdint.h>
#include <string.h>

#include <rcl/error_handling.h>
#include <rcl/publisher.h>
#include <rcl/subscription.h>
#include <rcutils/allocator.h>
#include <rmw/serialized_message.h>

#define LOOP_K 0
#define LOOP_GATE 1
#define LOOP_LIMIT 2
#define LOOP_COUNT 3
#define LOOP_OUT 4
#define N_LOOP 6
#define LOOP_DONE 1
#define NOT_RUN (-1)

typedef int64_t (*loop_kernel)(const uint8_t *data, int64_t size, int64_t k, int64_t *context);

typedef struct Pump Pump;
typedef struct Entry Entry;

typedef struct {
    Entry *entry;  /* borrowed; NULL once its entry closed */
    rcl_serialized_message_t message;
} Held;

struct Entry {
    PyObject_HEAD
    vectorcallfunc vectorcall;
    Pump *pump;  /* NULL once closed */
    rcl_subscription_t *subscription;
    rcl_publisher_t *publisher;
    loop_kernel kernel;
    Py_buffer context;
    PyObject *handler;
    PyObject *kick;
};

struct Pump {
    PyObject_HEAD
    Entry **entries;  /* borrowed: an entry removes itself before it goes */
    Py_ssize_t n_entries;
    Py_ssize_t capacity;
    uint64_t generation;  /* changes with the entries: a handler may close one */
    long budget;
    int running;
    rcl_serialized_message_t message;  /* what the last take got */
    Held *held;  /* taken at the budget: every message then waiting, in the order taken */
    Py_ssize_t n_held, held_capacity;
    Entry *kicked;  /* borrowed: the entry whose kick is on its way, NULL: none */
    unsigned long long taken, holds;  /* messages it took itself; runs it ended holding one */
};

static PyTypeObject PumpType;
static PyTypeObject EntryType;

static PyObject *
rcl_failure(const char *what)
{
    PyErr_Format(PyExc_RuntimeError, "loop pump: %s failed: %s", what, rcl_get_error_string().str);
    rcl_reset_error();
    return NULL;
}

/* Run e's kernel on one message, publish where it completed; 0, or -1 with an exception set. */
static int
step_entry(Entry *e, const uint8_t *data, size_t size, PyObject *message)
{
    int64_t *c = (int64_t *)e->context.buf;
    int64_t k = c[LOOP_K];
    int64_t code = NOT_RUN;
    if (c[LOOP_GATE] && k < c[LOOP_LIMIT]) {
        code = e->kernel(data, (int64_t)size, k, c);
    }
    if (code == LOOP_DONE) {
        c[LOOP_K] = k + 1;
        c[LOOP_COUNT] += 1;
        rcl_serialized_message_t answer = {
            .buffer = (uint8_t *)(intptr_t)c[LOOP_OUT], .buffer_length = (size_t)c[LOOP_OUT + 1],
            .buffer_capacity = (size_t)c[LOOP_OUT + 1], .allocator = rcutils_get_default_allocator()};
        if (rcl_publish_serialized_message(e->publisher, &answer, NULL) != RCL_RET_OK) {
            rcl_failure("publishing the answer");
            return -1;
        }
        return 0;
    }
    PyObject *owned = NULL;
    if (message == NULL) {
        message = owned = PyBytes_FromStringAndSize((const char *)data, (Py_ssize_t)size);
        if (message == NULL) {
            return -1;
        }
    }
    Py_INCREF(e);  /* the handler may close the entry and drop the last other reference */
    PyObject *result = PyObject_CallFunction(e->handler, "OL", message, (long long)code);
    Py_DECREF(e);
    Py_XDECREF(owned);
    if (result == NULL) {
        return -1;
    }
    Py_DECREF(result);
    return 0;
}

/* Take the next waiting message of any entry into `into`; the entry's index or -1. */
static Py_ssize_t
take_into(Pump *p, Py_ssize_t after, rcl_serialized_message_t *into)
{
    rmw_message_info_t info;
    for (Py_ssize_t i = 1; i <= p->n_entries; i++) {
        Py_ssize_t j = (after + i) % p->n_entries;
        rcl_ret_t ret = rcl_take_serialized_message(p->entries[j]->subscription, into, &info, NULL);
        if (ret == RCL_RET_OK) {
            return j;
        }
        if (ret != RCL_RET_SUBSCRIPTION_TAKE_FAILED) {
            rcl_reset_error();  /* the executor's own take reports it */
        }
    }
    return -1;
}

static Py_ssize_t
entry_index(Pump *p, Entry *e)
{
    for (Py_ssize_t i = 0; i < p->n_entries; i++) {
        if (p->entries[i] == e) {
            return i;
        }
    }
    return -1;
}

/* Take every waiting message into the held list and kick the first one's entry; 0, or -1 with an
 * exception set. All of them: a message left waiting (a pipelined controller keeps two in flight)
 * would be taken by the first of the executor's events queued for its subscription, restarting the
 * pump ahead of everything else queued, and those events would pile up without bound. */
static int
hold_waiting(Pump *p, Py_ssize_t at)
{
    for (;;) {
        if (p->n_held == p->held_capacity) {
            Py_ssize_t capacity = p->held_capacity ? 2 * p->held_capacity : 4;
            Held *grown = PyMem_Realloc(p->held, (size_t)capacity * sizeof(Held));
            if (grown == NULL) {
                PyErr_NoMemory();
                return -1;
            }
            p->held = grown;
            rcutils_allocator_t allocator = rcutils_get_default_allocator();
            for (Py_ssize_t i = p->held_capacity; i < capacity; i++) {
                p->held[i].entry = NULL;
                p->held[i].message = rmw_get_zero_initialized_serialized_message();
                if (rmw_serialized_message_init(&p->held[i].message, 256, &allocator) != RMW_RET_OK) {
                    p->held_capacity = i;
                    rcl_failure("allocating a held message");
                    return -1;
                }
            }
            p->held_capacity = capacity;
        }
        at = take_into(p, at, &p->held[p->n_held].message);
        if (at < 0) {
            break;
        }
        p->held[p->n_held++].entry = p->entries[at];
        p->taken++;
    }
    if (p->n_held == 0) {
        return 0;
    }
    p->holds++;
    if (p->kicked != NULL) {  /* one kick at a time: each would start a run of its own */
        return 0;
    }
    p->kicked = p->held[0].entry;
    PyObject *result = PyObject_CallNoArgs(p->kicked->kick);
    Py_XDECREF(result);
    return result == NULL ? -1 : 0;
}

/* The pump from the held messages (if any), then `first`'s message (if given), then what waits. */
static PyObject *
pump_run(Pump *p, Entry *first, const uint8_t *data, size_t size, PyObject *message)
{
    Py_INCREF(p);
    p->running = 1;
    int err = 0;
    Entry *last = first;
    Py_ssize_t n_held = p->n_held;
    p->n_held = 0;
    for (Py_ssize_t i = 0; !err && i < n_held; i++) {  /* taken before `first`'s message: they go first */
        Held *h = &p->held[i];
        if (h->entry != NULL) {
            last = h->entry;
            err = step_entry(h->entry, h->message.buffer, h->message.buffer_length, NULL);
        }
    }
    if (!err && first != NULL) {
        last = first;
        err = step_entry(first, data, size, message);
    }
    Py_ssize_t at = last != NULL ? entry_index(p, last) : -1;
    uint64_t generation = p->generation;
    for (long taken = 0; !err && at >= 0 && p->budget > 0 && p->generation == generation; taken++) {
        if (taken >= p->budget) {  /* hold what waits and let the executor have its turn */
            err = hold_waiting(p, at);
            break;
        }
        at = take_into(p, at, &p->message);
        if (at >= 0) {
            p->taken++;
            err = step_entry(p->entries[at], p->message.buffer, p->message.buffer_length, NULL);
        }
    }
    p->running = 0;
    Py_DECREF(p);
    return err ? NULL : Py_NewRef(Py_None);
}

static PyObject *
Entry_vectorcall(PyObject *obj, PyObject *const *args, size_t nargsf, PyObject *kwnames)
{
    Entry *e = (Entry *)obj;
    if (PyVectorcall_NARGS(nargsf) != 1 || kwnames != NULL) {
        PyErr_SetString(PyExc_TypeError, "a loop pump entry takes one positional argument: the message");
        return NULL;
    }
    Py_buffer view;
    if (PyObject_GetBuffer(args[0], &view, PyBUF_C_CONTIGUOUS) < 0) {
        return NULL;
    }
    PyObject *result;
    if (e->pump == NULL || e->pump->running) {  /* closed, or called from a handler: this message only */
        result = step_entry(e, view.buf, (size_t)view.len, args[0]) ? NULL : Py_NewRef(Py_None);
    } else {
        result = pump_run(e->pump, e, view.buf, (size_t)view.len, args[0]);
    }
    PyBuffer_Release(&view);
    return result;
}

static PyObject *
Entry_resume(PyObject *obj, PyObject *Py_UNUSED(ignored))
{
    Pump *p = ((Entry *)obj)->pump;
    if (p != NULL && p->kicked == (Entry *)obj) {
        p->kicked = NULL;
    }
    if (p == NULL || p->running || p->n_held == 0) {
        Py_RETURN_NONE;
    }
    return pump_run(p, NULL, NULL, 0, NULL);
}

static void
entry_detach(Entry *e)
{
    Pump *p = e->pump;
    if (p == NULL) {
        return;
    }
    Py_ssize_t i = entry_index(p, e);
    if (i >= 0) {
        memmove(&p->entries[i], &p->entries[i + 1], (size_t)(p->n_entries - i - 1) * sizeof(Entry *));
        p->n_entries--;
    }
    for (Py_ssize_t j = 0; j < p->n_held; j++) {
        if (p->held[j].entry == e) {
            p->held[j].entry = NULL;  /* its node goes: nobody takes the message */
        }
    }
    if (p->kicked == e) {
        p->kicked = NULL;  /* what others hold goes with the next message the executor hands over */
    }
    p->generation++;
    e->pump = NULL;
    Py_DECREF(p);
}

static PyObject *
Entry_close(PyObject *obj, PyObject *Py_UNUSED(ignored))
{
    entry_detach((Entry *)obj);
    Py_RETURN_NONE;
}

static PyObject *
Entry_get_open(PyObject *obj, void *Py_UNUSED(closure))
{
    return PyBool_FromLong(((Entry *)obj)->pump != NULL);
}

/* inspect.signature(entry) is (data, /): rclpy checks a subscription callback's signature */
static PyObject *
Entry_get_signature(PyObject *Py_UNUSED(obj), void *Py_UNUSED(closure))
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

static int
Entry_traverse(PyObject *obj, visitproc visit, void *arg)
{
    Entry *e = (Entry *)obj;
    Py_VISIT(e->handler);
    Py_VISIT(e->kick);
    Py_VISIT(e->context.obj);
    return 0;
}

static int
Entry_clear(PyObject *obj)
{
    Entry *e = (Entry *)obj;
    Py_CLEAR(e->handler);
    Py_CLEAR(e->kick);
    return 0;
}

static void
Entry_dealloc(PyObject *obj)
{
    Entry *e = (Entry *)obj;
    PyObject_GC_UnTrack(obj);
    entry_detach(e);
    Py_CLEAR(e->handler);
    Py_CLEAR(e->kick);
    if (e->context.obj != NULL) {
        PyBuffer_Release(&e->context);
    }
    Py_TYPE(obj)->tp_free(obj);
}

static PyObject *
Pump_add(PyObject *obj, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"subscription", "publisher", "kernel", "context", "handler", "kick", NULL};
    Pump *p = (Pump *)obj;
    unsigned long long sub, pub, kernel;
    PyObject *context, *handler, *kick;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "KKKOOO", kwlist, &sub, &pub, &kernel, &context, &handler,
                                     &kick)) {
        return NULL;
    }
    if (sub == 0 || pub == 0 || kernel == 0) {
        PyErr_SetString(PyExc_ValueError, "Pump.add: a subscription, publisher or kernel address is 0");
        return NULL;
    }
    if (!PyCallable_Check(handler) || !PyCallable_Check(kick)) {
        PyErr_SetString(PyExc_TypeError, "Pump.add: handler must be callable as handler(data, code), kick as kick()");
        return NULL;
    }
    Entry *e = PyObject_GC_New(Entry, &EntryType);
    if (e == NULL) {
        return NULL;
    }
    e->vectorcall = Entry_vectorcall;
    e->pump = NULL;
    e->handler = NULL;
    e->kick = NULL;
    e->context.obj = NULL;
    if (PyObject_GetBuffer(context, &e->context, PyBUF_WRITABLE | PyBUF_C_CONTIGUOUS | PyBUF_FORMAT) < 0) {
        e->context.obj = NULL;
        Py_DECREF(e);
        return NULL;
    }
    if (e->context.itemsize != 8 || e->context.format == NULL || strchr("qlL", e->context.format[0]) == NULL
        || e->context.len < N_LOOP * 8) {
        PyErr_SetString(PyExc_ValueError, "Pump.add: context must be an int64 buffer of at least 6 words");
        Py_DECREF(e);
        return NULL;
    }
    if (p->n_entries == p->capacity) {
        Py_ssize_t capacity = p->capacity ? 2 * p->capacity : 4;
        Entry **grown = PyMem_Realloc(p->entries, (size_t)capacity * sizeof(Entry *));
        if (grown == NULL) {
            Py_DECREF(e);
            return PyErr_NoMemory();
        }
        p->capacity = capacity;
        p->entries = grown;
    }
    e->subscription = (rcl_subscription_t *)(uintptr_t)sub;
    e->publisher = (rcl_publisher_t *)(uintptr_t)pub;
    e->kernel = (loop_kernel)(uintptr_t)kernel;
    e->handler = Py_NewRef(handler);
    e->kick = Py_NewRef(kick);
    e->pump = (Pump *)Py_NewRef(obj);
    p->entries[p->n_entries++] = e;
    p->generation++;
    PyObject_GC_Track((PyObject *)e);
    return (PyObject *)e;
}

static PyObject *
Pump_get_entries(PyObject *obj, void *Py_UNUSED(closure))
{
    return PyLong_FromSsize_t(((Pump *)obj)->n_entries);
}

static PyObject *
Pump_get_taken(PyObject *obj, void *Py_UNUSED(closure))
{
    return PyLong_FromUnsignedLongLong(((Pump *)obj)->taken);
}

static PyObject *
Pump_get_holds(PyObject *obj, void *Py_UNUSED(closure))
{
    return PyLong_FromUnsignedLongLong(((Pump *)obj)->holds);
}

static PyObject *
Pump_new(PyTypeObject *type, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"budget", NULL};
    long budget = 256;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "|l", kwlist, &budget)) {
        return NULL;
    }
    if (budget < 0) {
        PyErr_SetString(PyExc_ValueError, "Pump: budget must be >= 0 (messages taken per call)");
        return NULL;
    }
    Pump *p = (Pump *)type->tp_alloc(type, 0);
    if (p == NULL) {
        return NULL;
    }
    p->budget = budget;
    p->message = rmw_get_zero_initialized_serialized_message();

    rcutils_allocator_t allocator = rcutils_get_default_allocator();
    if (rmw_serialized_message_init(&p->message, 256, &allocator) != RMW_RET_OK) {
        Py_DECREF(p);
        return rcl_failure("allocating the message buffers");
    }
    return (PyObject *)p;
}

static void
Pump_dealloc(PyObject *obj)
{
    Pump *p = (Pump *)obj;
    PyMem_Free(p->entries);  /* empty: every entry holds a reference to its pump */
    if (p->message.buffer != NULL && rmw_serialized_message_fini(&p->message) != RMW_RET_OK) {
        rcl_reset_error();
    }
    for (Py_ssize_t i = 0; i < p->held_capacity; i++) {
        if (rmw_serialized_message_fini(&p->held[i].message) != RMW_RET_OK) {
            rcl_reset_error();
        }
    }
    PyMem_Free(p->held);
    Py_TYPE(obj)->tp_free(obj);
}

static PyMethodDef Entry_methods[] = {
    {"close", Entry_close, METH_NOARGS, "Remove the entry from its pump (idempotent)."},
    {"resume", Entry_resume, METH_NOARGS, "Run the pump from the message it holds, if any."},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Entry_getset[] = {
    {"open", Entry_get_open, NULL, "False once closed.", NULL},
    {"__signature__", Entry_get_signature, NULL, "(data, /)", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject EntryType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "ambid_nodes._loop_pump.Entry",
    .tp_doc = "A loop node's subscription in a Pump; call it with a message to run the pump from there.",
    .tp_basicsize = sizeof(Entry),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_VECTORCALL | Py_TPFLAGS_HAVE_GC,
    .tp_vectorcall_offset = offsetof(Entry, vectorcall),
    .tp_call = PyVectorcall_Call,
    .tp_dealloc = Entry_dealloc,
    .tp_traverse = Entry_traverse,
    .tp_clear = Entry_clear,
    .tp_methods = Entry_methods,
    .tp_getset = Entry_getset,
};

static PyMethodDef Pump_methods[] = {
    {"add", (PyCFunction)(void (*)(void))Pump_add, METH_VARARGS | METH_KEYWORDS,
     "add(subscription, publisher, kernel, context, handler, kick) -> Entry"},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Pump_getset[] = {
    {"entries", Pump_get_entries, NULL, "The number of open entries.", NULL},
    {"taken", Pump_get_taken, NULL, "Messages the pump took itself (not through the executor).", NULL},
    {"holds", Pump_get_holds, NULL, "Runs that ended at the budget, holding the next message.", NULL},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject PumpType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "ambid_nodes._loop_pump.Pump",
    .tp_doc = "Pump(budget=256): runs the loop nodes' kernels on their messages (see the module).",
    .tp_basicsize = sizeof(Pump),
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_new = Pump_new,
    .tp_dealloc = Pump_dealloc,
    .tp_methods = Pump_methods,
    .tp_getset = Pump_getset,
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_loop_pump", "Take, step and answer the lock-step loop's messages in compiled code.",
    -1, NULL,
};

PyMODINIT_FUNC
PyInit__loop_pump(void)
{
    if (PyType_Ready(&PumpType) < 0 || PyType_Ready(&EntryType) < 0) {
        return NULL;
    }
    PyObject *m = PyModule_Create(&module);
    if (m == NULL) {
        return NULL;
    }
    if (PyModule_AddObjectRef(m, "Pump", (PyObject *)&PumpType) < 0
        || PyModule_AddObjectRef(m, "Entry", (PyObject *)&EntryType) < 0
        || PyModule_AddIntConstant(m, "NOT_RUN", NOT_RUN) < 0 || PyModule_AddIntConstant(m, "LOOP_DONE", LOOP_DONE) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
