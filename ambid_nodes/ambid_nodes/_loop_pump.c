/* ambid_nodes._loop_pump: take, step and answer the lock-step loop's messages in compiled code.
 *
 * Per sample the loop is two messages: the plant's y[k] and the controller's
 * answer. Through rclpy each costs an executor dispatch, a Python callback and
 * a publish call, several times the work of the compiled kernels
 * (loop_kernels.py). A Pump runs the loop nodes' kernels on the messages
 * itself: it takes a message from an entry's subscription with rcl, runs the
 * entry's kernel, publishes the answer with rcl, and goes on with the next
 * message of any entry, until none is waiting or it has taken `budget`
 * messages. Composed in one process, Fast DDS hands a message to a
 * subscription of the same process during the publish call, so the plant and
 * controller answer each other without leaving this loop; as separate
 * processes each process's pump takes its one message and returns.
 *
 * The entries' subscriptions are not the executor's: rmw tells the pump of a
 * new message through the subscription's new-message callback, on the thread
 * that delivers it (the publisher's, or a Fast DDS receive thread). While the
 * pump runs it takes that message anyway; otherwise the callback sends a
 * kick, a message on the entry's hidden kick topic, which the node subscribes
 * to through the executor and whose callback calls entry.resume(). So the
 * pump always runs on the executor's thread, in order with everything else
 * queued there, and nothing else of the nodes runs meanwhile (no locks on
 * their state). One kick at a time: each would start a run of its own. After
 * `budget` messages the pump takes every message then waiting (two, with a
 * pipelined controller), holds them and kicks: timers, services and other
 * subscribers (of the loop topics too) get their turn first. A subscriber of
 * the loop topics in the same process gets up to budget / 2 messages per
 * turn: its queue must be at least that deep (qos.LOOP: 100).
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
 *     pump.add(subscription, publisher, kernel, context, handler, kick_publisher, kick, keep) -> Entry
 *         subscription, publisher, kick_publisher: rcl_subscription_t / rcl_publisher_t
 *         addresses (rclpy's handle.pointer; the caller keeps the handles alive until
 *         entry.close()); the subscription must be no executor's (the pump sets its
 *         new-message callback); kernel: the cfunc's address; context: a writable
 *         C-contiguous int64 buffer; kick: the serialised kick message (bytes);
 *         keep: held until the entry goes (the rclpy objects owning those addresses)
 *     entry.resume()  the kick's callback: run the pump (held messages first)
 *     entry.close()   out of the pump, its callback cleared (idempotent; drops messages held for it)
 *
 * Session identity. rmw gives every taken message its publisher's GID; an entry can accept the
 * messages of one publisher only (its session's partner: ambid_nodes.identity), checked before the
 * kernel runs (a 16-byte compare, nothing else on the per-sample path):
 *     entry.accept(b"")     any publisher (the default; a node without a session)
 *     entry.accept(gid)     only the publisher of this 16-byte GID; the others are foreign: counted
 *                           (entry.foreign), never run nor handed to the handler, and the first message
 *                           of each foreign publisher calls entry.on_foreign(gid) (to name it)
 *     entry.accept(None)    the partner is not known yet: every message goes to
 *                           entry.on_unknown(data, gid), which decides (foreign if it is None)
 * An entry with kernel 0 (and publisher 0) is a tap: every message goes to its handler, with the
 * same check (the recorder takes /clock so). publisher_gid(address) is the GID of an rcl publisher.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <stdatomic.h>
#include <stdint.h>
#include <string.h>

#include <rcl/error_handling.h>
#include <rcl/publisher.h>
#include <rmw/rmw.h>
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
#define GID_SIZE RMW_GID_STORAGE_SIZE
#define FILTER_OPEN 0   /* any publisher */
#define FILTER_GID 1    /* only the partner's GID */
#define FILTER_NONE 2   /* partner not known yet: on_unknown decides */
#define N_SEEN 16       /* foreign publishers named one by one; more are counted only */

typedef int64_t (*loop_kernel)(const uint8_t *data, int64_t size, int64_t k, int64_t *context);

typedef struct Pump Pump;
typedef struct Entry Entry;

typedef struct {
    Entry *entry;  /* borrowed; NULL once its entry closed */
    rcl_serialized_message_t message;
    uint8_t gid[GID_SIZE];  /* its publisher */
} Held;

struct Entry {
    PyObject_HEAD
    Pump *pump;  /* NULL once closed */
    rcl_subscription_t *subscription;
    rcl_publisher_t *publisher;
    loop_kernel kernel;
    Py_buffer context;
    PyObject *handler;
    rcl_publisher_t *kick_publisher;
    rcl_serialized_message_t kick;  /* its buffer: a copy the entry owns */
    int listening;  /* its new-message callback is set */
    PyObject *keep;  /* the rclpy handles of the addresses: alive while the entry is (not traversed) */
    int filter;  /* FILTER_* */
    uint8_t partner[GID_SIZE];
    unsigned long long foreign;  /* messages of other publishers, dropped */
    PyObject *on_foreign;  /* on_foreign(gid) at the first message of each foreign publisher, or NULL */
    PyObject *on_unknown;  /* with FILTER_NONE: on_unknown(data, gid), or NULL */
    uint8_t seen[N_SEEN][GID_SIZE];  /* foreign publishers already named */
    int n_seen;
};

struct Pump {
    PyObject_HEAD
    Entry **entries;  /* borrowed: an entry removes itself before it goes */
    Py_ssize_t n_entries;
    Py_ssize_t capacity;
    uint64_t generation;  /* changes with the entries: a handler may close one */
    long budget;
    atomic_int running;  /* a run is on (on the executor's thread) */
    atomic_int arrived;  /* a message came while it ran: look again before stopping */
    atomic_int kicked;  /* a kick is on its way */
    rcl_serialized_message_t message;  /* what the last take got */
    uint8_t gid[GID_SIZE];  /* and its publisher */
    Held *held;  /* taken at the budget: every message then waiting, in the order taken */
    Py_ssize_t n_held, held_capacity;
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

/* Send e's kick unless one is on its way; any thread, no GIL. */
static void
kick_once(Pump *p, Entry *e)
{
    if (atomic_exchange(&p->kicked, 1)) {
        return;
    }
    if (rcl_publish_serialized_message(e->kick_publisher, &e->kick, NULL) != RCL_RET_OK) {
        rcl_reset_error();  /* the context is going: nothing left to resume */
        atomic_store(&p->kicked, 0);
    }
}

/* rmw's new-message callback of an entry's subscription, on the thread that delivers the message. */
static void
on_new_message(const void *user_data, size_t number_of_events)
{
    (void)number_of_events;
    Entry *e = (Entry *)user_data;
    Pump *p = e->pump;  /* set while the callback is (entry_detach clears the callback first) */
    atomic_store(&p->arrived, 1);
    if (!atomic_load(&p->running)) {
        kick_once(p, e);
    }
}

/* fn(*args), e kept alive meanwhile (fn may close it and drop its last other reference); steals args;
 * 0, or -1 with an exception set (also where building args failed: args NULL). */
static int
call_python(Entry *e, PyObject *fn, PyObject *args)
{
    if (args == NULL) {
        return -1;
    }
    Py_INCREF(e);
    PyObject *result = PyObject_CallObject(fn, args);
    Py_DECREF(e);
    Py_DECREF(args);
    if (result == NULL) {
        return -1;
    }
    Py_DECREF(result);
    return 0;
}

/* A message of a publisher e does not accept: counted, dropped; its first one named through on_foreign.
 * 0, or -1 with an exception set. */
static int
foreign_message(Entry *e, const uint8_t *gid)
{
    e->foreign++;
    for (int i = 0; i < e->n_seen; i++) {
        if (memcmp(e->seen[i], gid, GID_SIZE) == 0) {
            return 0;
        }
    }
    if (e->n_seen == N_SEEN) {
        return 0;  /* a flood of publishers: counted, no more names */
    }
    memcpy(e->seen[e->n_seen++], gid, GID_SIZE);
    if (e->on_foreign == NULL) {
        return 0;
    }
    return call_python(e, e->on_foreign, Py_BuildValue("(y#)", (const char *)gid, (Py_ssize_t)GID_SIZE));
}

/* Run e's kernel on one message of publisher gid, publish where it completed; 0, or -1 with an exception set. */
static int
step_entry(Entry *e, const uint8_t *data, size_t size, const uint8_t *gid)
{
    if (e->filter != FILTER_OPEN && !(e->filter == FILTER_GID && memcmp(gid, e->partner, GID_SIZE) == 0)) {
        if (e->filter == FILTER_GID || e->on_unknown == NULL) {
            return foreign_message(e, gid);
        }
        return call_python(e, e->on_unknown, Py_BuildValue("(y#y#)", (const char *)data, (Py_ssize_t)size,
                                                           (const char *)gid, (Py_ssize_t)GID_SIZE));
    }
    int64_t *c = (int64_t *)e->context.buf;
    int64_t k = c[LOOP_K];
    int64_t code = NOT_RUN;
    if (e->kernel != NULL && c[LOOP_GATE] && k < c[LOOP_LIMIT]) {
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
    return call_python(e, e->handler, Py_BuildValue("(y#L)", (const char *)data, (Py_ssize_t)size, (long long)code));
}

/* Take the next waiting message of any entry into `into`, its publisher's GID into `gid`; the entry's
 * index or -1. */
static Py_ssize_t
take_into(Pump *p, Py_ssize_t after, rcl_serialized_message_t *into, uint8_t *gid)
{
    rmw_message_info_t info;
    for (Py_ssize_t i = 1; i <= p->n_entries; i++) {
        Py_ssize_t j = (after + i) % p->n_entries;
        rcl_ret_t ret = rcl_take_serialized_message(p->entries[j]->subscription, into, &info, NULL);
        if (ret == RCL_RET_OK) {
            memcpy(gid, info.publisher_gid.data, GID_SIZE);
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
 * exception set. All of them (a pipelined controller keeps two in flight): while the executor owned
 * the subscriptions, a message left waiting was taken by the first of its events queued there and
 * restarted the pump ahead of everything else. The subscriptions are the pump's now, but leaving
 * the messages in their queues instead made a test that times designs against the plant's progress
 * (test_excitation_generator) fail 1 run in 4, for a reason not pinned down: kept. */
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
        at = take_into(p, at, &p->held[p->n_held].message, p->held[p->n_held].gid);
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
    kick_once(p, p->held[0].entry);
    return 0;
}

/* The pump from the held messages (if any), then what waits, starting after entry `from`. */
static PyObject *
pump_run(Pump *p, Entry *from)
{
    Py_INCREF(p);
    atomic_store(&p->running, 1);
    atomic_store(&p->arrived, 0);
    int err = 0;
    Entry *last = from;
    Py_ssize_t n_held = p->n_held;
    p->n_held = 0;
    for (Py_ssize_t i = 0; !err && i < n_held; i++) {  /* taken before anything waiting now */
        Held *h = &p->held[i];
        if (h->entry != NULL) {
            last = h->entry;
            err = step_entry(h->entry, h->message.buffer, h->message.buffer_length, h->gid);
        }
    }
    Py_ssize_t at = last != NULL ? entry_index(p, last) : -1;
    uint64_t generation = p->generation;
    for (long taken = 0; !err && at >= 0 && p->generation == generation; taken++) {
        if (taken >= p->budget) {  /* hold what waits and let the executor have its turn */
            err = hold_waiting(p, at);
            break;
        }
        Py_ssize_t next = take_into(p, at, &p->message, p->gid);
        if (next < 0) {
            /* none waits: stop, unless one came meanwhile (its callback saw the run on) */
            atomic_store(&p->running, 0);
            if (!atomic_exchange(&p->arrived, 0)) {
                break;
            }
            atomic_store(&p->running, 1);
            continue;
        }
        at = next;
        p->taken++;
        err = step_entry(p->entries[at], p->message.buffer, p->message.buffer_length, p->gid);
    }
    atomic_store(&p->running, 0);
    if (atomic_exchange(&p->arrived, 0) && p->n_held == 0 && p->n_entries > 0) {
        kick_once(p, p->entries[0]);  /* it stopped early (an error, entries changed): come back */
    }
    Py_DECREF(p);
    return err ? NULL : Py_NewRef(Py_None);
}

static PyObject *
Entry_resume(PyObject *obj, PyObject *Py_UNUSED(ignored))
{
    Entry *e = (Entry *)obj;
    Pump *p = e->pump;
    if (p == NULL || atomic_load(&p->running)) {  /* closed, or called from a handler */
        Py_RETURN_NONE;
    }
    atomic_store(&p->kicked, 0);  /* before the run: a message after it kicks again */
    return pump_run(p, e);
}

static void
entry_detach(Entry *e)
{
    Pump *p = e->pump;
    if (p == NULL) {
        return;
    }
    if (e->listening) {  /* rmw returns once no callback runs: none comes after */
        if (rcl_subscription_set_on_new_message_callback(e->subscription, NULL, NULL) != RCL_RET_OK) {
            rcl_reset_error();
        }
        e->listening = 0;
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

static PyObject *
Entry_accept(PyObject *obj, PyObject *gid)
{
    Entry *e = (Entry *)obj;
    if (gid == Py_None) {
        e->filter = FILTER_NONE;
        Py_RETURN_NONE;
    }
    char *buf;
    Py_ssize_t len;
    if (PyBytes_AsStringAndSize(gid, &buf, &len) < 0) {
        return NULL;
    }
    if (len == 0) {
        e->filter = FILTER_OPEN;
    } else if (len == GID_SIZE) {
        memcpy(e->partner, buf, GID_SIZE);
        e->filter = FILTER_GID;
    } else {
        return PyErr_Format(PyExc_ValueError, "Entry.accept: a GID has %d bytes, got %zd", (int)GID_SIZE, len);
    }
    Py_RETURN_NONE;
}

static PyObject *
Entry_get_callback(PyObject *obj, void *closure)
{
    Entry *e = (Entry *)obj;
    PyObject *cb = closure ? e->on_unknown : e->on_foreign;
    return Py_NewRef(cb ? cb : Py_None);
}

static int
Entry_set_callback(PyObject *obj, PyObject *value, void *closure)
{
    Entry *e = (Entry *)obj;
    if (value != NULL && value != Py_None && !PyCallable_Check(value)) {
        PyErr_SetString(PyExc_TypeError, "Entry: on_foreign and on_unknown must be callable or None");
        return -1;
    }
    PyObject **slot = closure ? &e->on_unknown : &e->on_foreign;
    PyObject *old = *slot;
    *slot = (value == NULL || value == Py_None) ? NULL : Py_NewRef(value);
    Py_XDECREF(old);
    return 0;
}

static PyObject *
Entry_get_foreign(PyObject *obj, void *Py_UNUSED(closure))
{
    return PyLong_FromUnsignedLongLong(((Entry *)obj)->foreign);
}

static PyObject *
publisher_gid(PyObject *Py_UNUSED(module), PyObject *arg)
{
    unsigned long long address = PyLong_AsUnsignedLongLong(arg);
    if (address == (unsigned long long)-1 && PyErr_Occurred()) {
        return NULL;
    }
    if (address == 0) {
        PyErr_SetString(PyExc_ValueError, "publisher_gid: the publisher address is 0");
        return NULL;
    }
    rmw_publisher_t *rmw = rcl_publisher_get_rmw_handle((rcl_publisher_t *)(uintptr_t)address);
    if (rmw == NULL) {
        return rcl_failure("getting the publisher's rmw handle");
    }
    rmw_gid_t gid;
    if (rmw_get_gid_for_publisher(rmw, &gid) != RMW_RET_OK) {
        return rcl_failure("getting the publisher's GID");  /* rmw reports in rcutils' error state too */
    }
    return PyBytes_FromStringAndSize((const char *)gid.data, GID_SIZE);
}

static int
Entry_traverse(PyObject *obj, visitproc visit, void *arg)
{
    Entry *e = (Entry *)obj;
    Py_VISIT(e->handler);
    Py_VISIT(e->on_foreign);
    Py_VISIT(e->on_unknown);
    Py_VISIT(e->context.obj);
    return 0;
}

static int
Entry_clear(PyObject *obj)
{
    Entry *e = (Entry *)obj;
    Py_CLEAR(e->handler);
    Py_CLEAR(e->on_foreign);
    Py_CLEAR(e->on_unknown);
    return 0;
}

static void
Entry_dealloc(PyObject *obj)
{
    Entry *e = (Entry *)obj;
    PyObject_GC_UnTrack(obj);
    entry_detach(e);
    Py_CLEAR(e->handler);
    Py_CLEAR(e->on_foreign);
    Py_CLEAR(e->on_unknown);
    Py_CLEAR(e->keep);  /* after the callback is cleared */
    PyMem_Free(e->kick.buffer);
    if (e->context.obj != NULL) {
        PyBuffer_Release(&e->context);
    }
    Py_TYPE(obj)->tp_free(obj);
}

static PyObject *
Pump_add(PyObject *obj, PyObject *args, PyObject *kwds)
{
    static char *kwlist[] = {"subscription", "publisher", "kernel", "context", "handler", "kick_publisher", "kick",
                             "keep", NULL};
    Pump *p = (Pump *)obj;
    unsigned long long sub, pub, kernel, kick_pub;
    PyObject *context, *handler, *keep = Py_None;
    Py_buffer kick;
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "KKKOOKy*|O", kwlist, &sub, &pub, &kernel, &context, &handler,
                                     &kick_pub, &kick, &keep)) {
        return NULL;
    }
    if (sub == 0 || kick_pub == 0 || (pub == 0) != (kernel == 0)) {
        PyBuffer_Release(&kick);
        PyErr_SetString(PyExc_ValueError, "Pump.add: a subscription, publisher or kernel address is 0 (a tap has "
                                          "kernel and publisher 0, both)");
        return NULL;
    }
    if (!PyCallable_Check(handler)) {
        PyBuffer_Release(&kick);
        PyErr_SetString(PyExc_TypeError, "Pump.add: handler must be callable as handler(data, code)");
        return NULL;
    }
    size_t kick_len = (size_t)kick.len;
    uint8_t *kick_copy = PyMem_Malloc(kick_len > 0 ? kick_len : 1);
    if (kick_copy != NULL) {
        memcpy(kick_copy, kick.buf, kick_len);
    }
    PyBuffer_Release(&kick);
    if (kick_copy == NULL) {
        return PyErr_NoMemory();
    }
    Entry *e = PyObject_GC_New(Entry, &EntryType);
    if (e == NULL) {
        PyMem_Free(kick_copy);
        return NULL;
    }
    e->pump = NULL;
    e->handler = NULL;
    e->on_foreign = e->on_unknown = NULL;
    e->filter = FILTER_OPEN;
    e->foreign = 0;
    e->n_seen = 0;
    e->keep = Py_NewRef(keep);
    e->listening = 0;
    e->kick = (rcl_serialized_message_t){.buffer = kick_copy, .buffer_length = kick_len, .buffer_capacity = kick_len,
                                         .allocator = rcutils_get_default_allocator()};
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
    e->kick_publisher = (rcl_publisher_t *)(uintptr_t)kick_pub;
    e->handler = Py_NewRef(handler);
    e->pump = (Pump *)Py_NewRef(obj);
    p->entries[p->n_entries++] = e;
    p->generation++;
    PyObject_GC_Track((PyObject *)e);
    /* rmw calls it at once if messages wait already */
    if (rcl_subscription_set_on_new_message_callback(e->subscription, on_new_message, e) != RCL_RET_OK) {
        rcl_failure("setting the subscription's new-message callback");
        Py_DECREF(e);  /* detaches it */
        return NULL;
    }
    e->listening = 1;
    return (PyObject *)e;
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
        return rcl_failure("allocating the message buffer");
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
    {"resume", Entry_resume, METH_NOARGS, "The kick's callback: run the pump (held messages first)."},
    {"accept", Entry_accept, METH_O, "accept(gid): b'' any publisher, a 16-byte GID only that one, None none yet."},
    {NULL, NULL, 0, NULL},
};

static PyGetSetDef Entry_getset[] = {
    {"open", Entry_get_open, NULL, "False once closed.", NULL},
    {"foreign", Entry_get_foreign, NULL, "Messages of publishers it does not accept, dropped.", NULL},
    {"on_foreign", Entry_get_callback, Entry_set_callback, "on_foreign(gid): a foreign publisher's first message.",
     NULL},
    {"on_unknown", Entry_get_callback, Entry_set_callback, "on_unknown(data, gid): with accept(None), each message.",
     (void *)1},
    {NULL, NULL, NULL, NULL, NULL},
};

static PyTypeObject EntryType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "ambid_nodes._loop_pump.Entry",
    .tp_doc = "A loop node's subscription in a Pump (see the module).",
    .tp_basicsize = sizeof(Entry),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_HAVE_GC,
    .tp_dealloc = Entry_dealloc,
    .tp_traverse = Entry_traverse,
    .tp_clear = Entry_clear,
    .tp_methods = Entry_methods,
    .tp_getset = Entry_getset,
};

static PyMethodDef Pump_methods[] = {
    {"add", (PyCFunction)(void (*)(void))Pump_add, METH_VARARGS | METH_KEYWORDS,
     "add(subscription, publisher, kernel, context, handler, kick_publisher, kick, keep=None) -> Entry"},
    {NULL, NULL, 0, NULL},
};

static PyMemberDef Pump_members[] = {
    {"entries", T_PYSSIZET, offsetof(Pump, n_entries), READONLY, "The number of open entries."},
    {"taken", T_ULONGLONG, offsetof(Pump, taken), READONLY, "Messages the pump took."},
    {"holds", T_ULONGLONG, offsetof(Pump, holds), READONLY, "Runs that ended at the budget, holding what waited."},
    {NULL, 0, 0, 0, NULL},
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
    .tp_members = Pump_members,
};

static PyMethodDef module_methods[] = {
    {"publisher_gid", publisher_gid, METH_O, "publisher_gid(address) -> bytes: the GID of an rcl publisher."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_loop_pump", "Take, step and answer the lock-step loop's messages in compiled code.",
    -1, module_methods,
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
        || PyModule_AddIntConstant(m, "NOT_RUN", NOT_RUN) < 0 || PyModule_AddIntConstant(m, "LOOP_DONE", LOOP_DONE) < 0
        || PyModule_AddIntConstant(m, "GID_SIZE", GID_SIZE) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
