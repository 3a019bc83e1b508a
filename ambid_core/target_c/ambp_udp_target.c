/* ambp_udp_target: a POSIX example real-time target for the ambid bridge protocol.
 *
 * Runs a discrete linear plant (u [A] -> y [m], with sensor noise) and a discrete position controller
 * (y -> ic [A], saturated), both loaded from a model file that `ambid target-model` writes, at a fixed
 * rate paced by clock_nanosleep on absolute deadlines, and serves them over UDP to one hardware bridge
 * through the portable protocol core ambp.c. Options mirror python -m ambid.hardware.rt_target.
 *
 *   ambp_udp_target --model FILE --bind HOST:PORT --bridge HOST:PORT --key-file KEY [--pace P] [--samples N] ...
 *
 * Protocol version 3 (the default) authenticates every datagram with the rig's key (--key-file, a file only
 * its owner may read; `ambid keygen --out FILE` writes one); version 2 (--protocol-version 2, the bridge
 * must ask for it too) is unauthenticated, and every start says so on stderr.
 *
 * Prints RT_TARGET_LISTENING host:port, and RT_TARGET_SUMMARY {json} on exit. Exit code 0 after a
 * DONE session, 1 otherwise, 2 for bad options or a bad model file (one line on stderr).
 */
#define _POSIX_C_SOURCE 200809L

#include "ambp.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <netdb.h>
#include <netinet/in.h>
#include <poll.h>
#include <sched.h>
#include <signal.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/mman.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#define MAX_STATES 1024
#define LAG_OVERRUN_NS 10000000ull /* behind schedule by more than 10 ms: an overrun (the protocol's) */
#define FREE_RUN_POLL 16           /* free-running: look at the socket every this many samples */

static volatile sig_atomic_t g_stop = 0;
static void on_signal(int sig) { (void)sig; g_stop = 1; }

static void die2(const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    fputs("ambp_udp_target: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    exit(2);
}

static uint64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

/* ---- the model file ---------------------------------------------------------------------------- */
typedef struct {
    int n, p, q;       /* states, inputs, outputs */
    double *a, *b, *c, *d;
} ss_model;

typedef struct {
    double dt, current_limit, controller_limit, noise_std[AMBP_MAX_AXES];
    int axes;          /* na: the channels of everything below, in the model file's axis order */
    ss_model plant, ctl;
} target_model;

typedef struct {
    FILE *f;
    const char *path;
    int line;
    char tok[128];
} reader;

static const char *next_token(reader *r) {
    int ch;
    for (;;) {
        ch = fgetc(r->f);
        if (ch == '#') { while (ch != '\n' && ch != EOF) ch = fgetc(r->f); }
        if (ch == '\n') { r->line++; continue; }
        if (ch == ' ' || ch == '\t' || ch == '\r') continue;
        break;
    }
    if (ch == EOF) return NULL;
    size_t n = 0;
    while (ch != EOF && ch != ' ' && ch != '\t' && ch != '\n' && ch != '\r' && ch != '#') {
        if (ch == 0 || n + 1 >= sizeof r->tok)
            die2("model file %s line %d: not a text model file (binary data or a token too long); "
                 "write it with './launch_scripts/ambid target-model --out FILE'", r->path, r->line);
        r->tok[n++] = (char)ch;
        ch = fgetc(r->f);
    }
    r->tok[n] = 0;
    if (ch != EOF) ungetc(ch, r->f);
    return r->tok;
}

static void expect_word(reader *r, const char *word) {
    const char *t = next_token(r);
    if (!t)
        die2("model file %s is truncated at line %d: expected '%s'; write it again with "
             "'./launch_scripts/ambid target-model --out FILE'", r->path, r->line, word);
    if (strcmp(t, word) != 0)
        die2("model file %s line %d: expected '%s', found '%.40s'; write it with "
             "'./launch_scripts/ambid target-model --out FILE'", r->path, r->line, word, t);
}

static double read_number(reader *r, const char *what) {
    const char *t = next_token(r);
    if (!t)
        die2("model file %s is truncated at line %d: %s is missing; write it again with "
             "'./launch_scripts/ambid target-model --out FILE'", r->path, r->line, what);
    char *end;
    errno = 0;
    double v = strtod(t, &end);
    if (*end != 0 || end == t)
        die2("model file %s line %d: %s is '%.40s', not a number", r->path, r->line, what, t);
    if (!isfinite(v)) die2("model file %s line %d: %s is %s; every value must be finite", r->path, r->line, what, t);
    return v;
}

static int read_count(reader *r, const char *what, int lo, int hi) {
    double v = read_number(r, what);
    if (v != floor(v) || v < lo || v > hi)
        die2("model file %s line %d: %s = %g must be an integer in [%d, %d]", r->path, r->line, what, v, lo, hi);
    return (int)v;
}

static double *read_matrix(reader *r, const char *name, int rows, int cols) {
    expect_word(r, name);
    double *m = calloc((size_t)(rows * cols) + 1, sizeof(double));
    if (!m) die2("out of memory reading %s", name);
    char what[64];
    for (int i = 0; i < rows * cols; i++) {
        snprintf(what, sizeof what, "%s[%d][%d]", name, i / (cols ? cols : 1), i % (cols ? cols : 1));
        m[i] = read_number(r, what);
    }
    return m;
}

static void read_ss(reader *r, const char *prefix, ss_model *s, int p, int q) {
    char name[32];
    snprintf(name, sizeof name, "%s_states", prefix);
    expect_word(r, name);
    s->n = read_count(r, name, 0, MAX_STATES);
    s->p = p;
    s->q = q;
    snprintf(name, sizeof name, "%s_A", prefix); s->a = read_matrix(r, name, s->n, s->n);
    snprintf(name, sizeof name, "%s_B", prefix); s->b = read_matrix(r, name, s->n, p);
    snprintf(name, sizeof name, "%s_C", prefix); s->c = read_matrix(r, name, q, s->n);
    snprintf(name, sizeof name, "%s_D", prefix); s->d = read_matrix(r, name, q, p);
}

static void load_model(const char *path, target_model *m) {
    struct stat st;
    if (stat(path, &st) != 0)
        die2("model file %s: %s; write one with './launch_scripts/ambid target-model --out %s'", path,
             strerror(errno), path);
    if (S_ISDIR(st.st_mode)) die2("model file %s is a directory; give the model file's path", path);
    if (st.st_size == 0)
        die2("model file %s is empty; write it with './launch_scripts/ambid target-model --out %s'", path, path);
    reader r = {fopen(path, "rb"), path, 1, {0}};
    if (!r.f) die2("model file %s: %s", path, strerror(errno));
    const char *t = next_token(&r);
    if (!t || strcmp(t, "ambid_target_model") != 0)
        die2("model file %s is not an ambid target model (it must begin with 'ambid_target_model 2'); "
             "write it with './launch_scripts/ambid target-model --out FILE'", path);
    int version = read_count(&r, "format version", 0, 1000000);
    if (version != 1 && version != 2)
        die2("model file %s has format version %d; this program reads versions 1 and 2", path, version);
    expect_word(&r, "dt");
    m->dt = read_number(&r, "dt");
    if (!(m->dt > 0 && m->dt < 1))
        die2("model file %s: dt = %g s must be in (0, 1)", path, m->dt);
    double rate = 1.0 / m->dt;
    if (fabs(rate - floor(rate + 0.5)) > 1e-6 * rate)
        die2("model file %s: dt = %g s is not the period of a whole number of hertz", path, m->dt);
    m->axes = (int)AMBP_V1_AXES; /* version 1: the four radial axes */
    if (version == 2) {
        expect_word(&r, "axes");
        m->axes = read_count(&r, "axes", 1, (int)AMBP_MAX_AXES);
        for (int i = 0; i < m->axes; i++) /* the axes' names: for the people reading the file */
            if (!next_token(&r))
                die2("model file %s is truncated at line %d: the names of the %d axes are missing", path, r.line,
                     m->axes);
    }
    const int na = m->axes;
    expect_word(&r, "current_limit");
    m->current_limit = read_number(&r, "current_limit");
    if (!(m->current_limit > 0)) die2("model file %s: current_limit = %g A must be > 0", path, m->current_limit);
    expect_word(&r, "controller_limit");
    m->controller_limit = read_number(&r, "controller_limit");
    if (!(m->controller_limit > 0))
        die2("model file %s: controller_limit = %g A must be > 0", path, m->controller_limit);
    expect_word(&r, "noise_std");
    for (int i = 0; i < na; i++) {
        m->noise_std[i] = read_number(&r, "noise_std");
        if (m->noise_std[i] < 0) die2("model file %s: noise_std %g m must be >= 0", path, m->noise_std[i]);
    }
    read_ss(&r, "plant", &m->plant, na, na);
    for (int i = 0; i < na * na; i++)
        if (m->plant.d[i] != 0)
            die2("model file %s: plant_D must be zero (y[k] is measured before u[k] is applied)", path);
    read_ss(&r, "controller", &m->ctl, na, na);
    expect_word(&r, "end");
    if (next_token(&r)) die2("model file %s line %d: text after 'end'", path, r.line);
    fclose(r.f);
}

/* ---- the rig's key ------------------------------------------------------------------------------ */
#define KEYGEN_FIX "write one with 'ambid keygen --out FILE' and give the bridge and the target the same file"

/* The key of a key file only its owner may read: comment lines (#), blank lines, one line of 32 to 128 hex
 * digits (docs/bridge_protocol.md). Anything else is one line on stderr and exit code 2. */
static size_t load_key(const char *path, uint8_t key[AMBP_MAX_KEY_BYTES]) {
    struct stat st;
    if (stat(path, &st) != 0) {
        if (errno == ENOENT) die2("key file %s does not exist; " KEYGEN_FIX, path);
        die2("key file %s: %s; " KEYGEN_FIX, path, strerror(errno));
    }
    if (S_ISDIR(st.st_mode)) die2("key file %s is a folder; give the key file's path", path);
    if (!S_ISREG(st.st_mode)) die2("key file %s is not a regular file; " KEYGEN_FIX, path);
    if (st.st_mode & 077)
        die2("key file %s may be read by group or others (mode %04o); a rig's key is secret: run 'chmod 600 %s'",
             path, (unsigned)(st.st_mode & 07777), path);
    if (st.st_size == 0) die2("key file %s is empty; " KEYGEN_FIX, path);
    if (st.st_size > 4096)
        die2("key file %s has %lld bytes, not a key file (at most 4096); " KEYGEN_FIX, path, (long long)st.st_size);
    char text[4097];
    int fd = open(path, O_RDONLY);
    if (fd < 0) die2("key file %s: %s", path, strerror(errno));
    ssize_t got = read(fd, text, 4096);
    close(fd);
    if (got < 0) die2("key file %s: %s", path, strerror(errno));
    text[got] = 0;
    for (ssize_t i = 0; i < got; i++)
        if (text[i] == 0 || (unsigned char)text[i] > 127) die2("key file %s is not text (binary data); " KEYGEN_FIX, path);
    size_t n = 0;
    int lines = 0;
    for (char *line = text, *next; line && *line; line = next) {
        next = strchr(line, '\n');
        if (next) *next++ = 0;
        char *a = line, *b = line + strlen(line);
        while (*a == ' ' || *a == '\t' || *a == '\r') a++;
        while (b > a && (b[-1] == ' ' || b[-1] == '\t' || b[-1] == '\r')) *--b = 0;
        if (*a == 0 || *a == '#') continue;
        if (++lines > 1) continue;
        size_t digits = (size_t)(b - a);
        for (size_t i = 0; i < digits; i++)
            if (!strchr("0123456789abcdefABCDEF", a[i]))
                die2("key file %s: its key line is not an even number of hex digits; " KEYGEN_FIX, path);
        if (digits % 2) die2("key file %s: its key line is not an even number of hex digits; " KEYGEN_FIX, path);
        n = digits / 2;
        if (n < AMBP_MIN_KEY_BYTES || n > AMBP_MAX_KEY_BYTES)
            die2("key file %s holds a key of %zu bytes, a link key has %u to %u; " KEYGEN_FIX, path, n,
                 AMBP_MIN_KEY_BYTES, AMBP_MAX_KEY_BYTES);
        for (size_t i = 0; i < n; i++) {
            unsigned v;
            char pair[3] = {a[2 * i], a[2 * i + 1], 0};
            sscanf(pair, "%2x", &v);
            key[i] = (uint8_t)v;
        }
    }
    ambp_wipe(text, sizeof text);
    if (lines == 0) die2("key file %s holds no key (only comments or nothing); " KEYGEN_FIX, path);
    if (lines > 1)
        die2("key file %s holds %d lines besides comments, a key file one; " KEYGEN_FIX, path, lines);
    return n;
}

/* 32 bytes the OS's random source gives, different at every start: the seed of the target's session nonces */
static void random_seed(uint8_t seed[32]) {
    int fd = open("/dev/urandom", O_RDONLY);
    size_t got = 0;
    while (fd >= 0 && got < 32) {
        ssize_t r = read(fd, seed + got, 32 - got);
        if (r <= 0) break;
        got += (size_t)r;
    }
    if (fd >= 0) close(fd);
    if (got < 32) die2("cannot read 32 random bytes from /dev/urandom (the session nonces' seed)");
}

/* ---- noise: splitmix64 + Marsaglia polar, a stream per seed ------------------------------------ */
static uint64_t rng_state;
static double spare;
static int has_spare;
static double uniform(void) {
    uint64_t z = (rng_state += 0x9E3779B97F4A7C15ull);
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
    z ^= z >> 31;
    return (double)(z >> 11) * (1.0 / 9007199254740992.0);
}
static double normal(void) {
    if (has_spare) { has_spare = 0; return spare; }
    double u, v, s;
    do {
        u = 2 * uniform() - 1;
        v = 2 * uniform() - 1;
        s = u * u + v * v;
    } while (s >= 1 || s == 0);
    double f = sqrt(-2 * log(s) / s);
    spare = v * f;
    has_spare = 1;
    return u * f;
}

/* out = M x (+=: acc) for a rows x cols row-major M */
static void matvec(const double *m, const double *x, double *out, int rows, int cols, int acc) {
    for (int i = 0; i < rows; i++) {
        double s = acc ? out[i] : 0.0;
        const double *row = m + (size_t)i * cols;
        for (int j = 0; j < cols; j++) s += row[j] * x[j];
        out[i] = s;
    }
}

/* ---- options ----------------------------------------------------------------------------------- */
typedef struct {
    const char *model, *bind, *bridge, *key_file;
    double pace, heartbeat, bridge_timeout, safe_seconds, linger;
    long long samples, seed;
    int block, float32, hold, version, queue, priority;
} options;

static double opt_double(const char *name, const char *v, double lo, double hi) {
    char *end;
    double x = strtod(v, &end);
    if (*v == 0 || *end != 0 || !isfinite(x) || x < lo || x > hi)
        die2("option %s = '%s' must be a number in [%g, %g]", name, v, lo, hi);
    return x;
}

static long long opt_int(const char *name, const char *v, long long lo, long long hi) {
    char *end;
    errno = 0;
    long long x = strtoll(v, &end, 10);
    if (*v == 0 || *end != 0 || errno || x < lo || x > hi)
        die2("option %s = '%s' must be an integer in [%lld, %lld]", name, v, lo, hi);
    return x;
}

static struct sockaddr_in opt_address(const char *name, const char *text) {
    struct sockaddr_in a;
    memset(&a, 0, sizeof a);
    a.sin_family = AF_INET;
    const char *colon = strrchr(text, ':');
    char host[256];
    if (!colon || (size_t)(colon - text) >= sizeof host)
        die2("option %s = '%s' must be host:port, e.g. 127.0.0.1:50001", name, text);
    memcpy(host, text, (size_t)(colon - text));
    host[colon - text] = 0;
    long long port = opt_int(name, colon + 1, 0, 65535);
    a.sin_port = htons((uint16_t)port);
    if (host[0] == 0) { a.sin_addr.s_addr = htonl(INADDR_ANY); return a; }
    if (inet_pton(AF_INET, host, &a.sin_addr) == 1) return a;
    struct addrinfo hints, *res = NULL;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_INET;
    hints.ai_socktype = SOCK_DGRAM;
    if (getaddrinfo(host, NULL, &hints, &res) != 0 || !res)
        die2("option %s = '%s': cannot resolve host '%s'", name, text, host);
    a.sin_addr = ((struct sockaddr_in *)res->ai_addr)->sin_addr;
    freeaddrinfo(res);
    return a;
}

static const char *USAGE =
    "usage: ambp_udp_target --model FILE --bind HOST:PORT --bridge HOST:PORT --key-file KEY [--seed N] [--pace P]\n"
    "  [--samples N] [--block N] [--float32] [--heartbeat S] [--bridge-timeout S] [--safe-seconds S] [--linger S]\n"
    "  [--hold-for-excitation] [--protocol-version N] [--queue N] [--priority N]\n"
    "  --pace 1 = real time (clock_nanosleep on absolute deadlines), 0 = free-running, p = 1/p of real time\n"
    "  --key-file: the rig's key (protocol version 3); --protocol-version 2 runs unauthenticated, without it\n";

static void parse_options(int argc, char **argv, options *o) {
    memset(o, 0, sizeof *o);
    o->bind = "127.0.0.1:50001";
    o->bridge = "127.0.0.1:50002";
    o->pace = 1.0;
    o->heartbeat = 0.05;
    o->bridge_timeout = 0.5;
    o->safe_seconds = 0.2;
    o->linger = 1.0;
    o->block = 0; /* 0: the most of the model's axes, up to 10 */
    o->version = AMBP_VERSION;
    o->queue = 65536;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        if (!strcmp(a, "-h") || !strcmp(a, "--help")) { fputs(USAGE, stdout); exit(0); }
        if (!strcmp(a, "--float32")) { o->float32 = 1; continue; }
        if (!strcmp(a, "--hold-for-excitation")) { o->hold = 1; continue; }
        if (strncmp(a, "--", 2) != 0)
            die2("unexpected argument '%s'; options start with --, see --help", a);
        static const char *const with_value[] = {"--model", "--bind", "--bridge", "--seed", "--pace", "--samples",
            "--block", "--heartbeat", "--bridge-timeout", "--safe-seconds", "--linger", "--protocol-version",
            "--queue", "--priority", "--key-file", NULL};
        int known = 0;
        for (int k = 0; with_value[k]; k++) known |= !strcmp(a, with_value[k]);
        if (!known) die2("unknown option '%s'; see --help", a);
        if (i + 1 >= argc) die2("option %s needs a value; see --help", a);
        const char *v = argv[++i];
        if (!strcmp(a, "--model")) o->model = v;
        else if (!strcmp(a, "--bind")) o->bind = v;
        else if (!strcmp(a, "--bridge")) o->bridge = v;
        else if (!strcmp(a, "--seed")) o->seed = opt_int(a, v, 0, 9223372036854775807LL);
        else if (!strcmp(a, "--pace")) o->pace = opt_double(a, v, 0.0, 1e3);
        else if (!strcmp(a, "--samples")) o->samples = opt_int(a, v, 0, 4611686018427387904LL);
        else if (!strcmp(a, "--block")) o->block = (int)opt_int(a, v, 1, (long long)AMBP_MAX_MEAS_SAMPLES);
        else if (!strcmp(a, "--heartbeat")) o->heartbeat = opt_double(a, v, 1e-3, 10.0);
        else if (!strcmp(a, "--bridge-timeout")) o->bridge_timeout = opt_double(a, v, 1e-3, 3600.0);
        else if (!strcmp(a, "--safe-seconds")) o->safe_seconds = opt_double(a, v, 0.0, 60.0);
        else if (!strcmp(a, "--linger")) o->linger = opt_double(a, v, 0.0, 3600.0);
        else if (!strcmp(a, "--protocol-version")) o->version = (int)opt_int(a, v, 1, 255);
        else if (!strcmp(a, "--queue")) o->queue = (int)opt_int(a, v, 1024, 1 << 24);
        else if (!strcmp(a, "--priority")) o->priority = (int)opt_int(a, v, 1, 99);
        else if (!strcmp(a, "--key-file")) o->key_file = v;
    }
    if (!o->model) die2("--model FILE is required; write one with './launch_scripts/ambid target-model --out FILE'");
    if (o->hold && o->pace != 0)
        die2("--hold-for-excitation needs --pace 0 (a real-time target cannot wait)");
    if (o->priority && o->pace == 0)
        die2("--priority needs --pace > 0 (a free-running loop at real-time priority would starve the host)");
    if (o->version >= (int)AMBP_AUTH_VERSION && o->version != (int)AMBP_AUTH_VERSION)
        die2("--protocol-version %d is not implemented; this build speaks 3, 2 and 1", o->version);
    if (o->version == (int)AMBP_AUTH_VERSION && !o->key_file)
        die2("protocol version 3 authenticates every datagram: give --key-file KEY (the rig's key; " KEYGEN_FIX
             "), or run --protocol-version 2 on both ends for an unauthenticated link");
    if (o->version < (int)AMBP_AUTH_VERSION && o->key_file)
        die2("--key-file with --protocol-version %d: that version is unauthenticated; speak version 3 with the key, "
             "or leave --key-file out", o->version);
}

/* ---- the program ------------------------------------------------------------------------------- */
int main(int argc, char **argv) {
    options o;
    parse_options(argc, argv, &o);
    struct sockaddr_in bind_addr = opt_address("--bind", o.bind);
    struct sockaddr_in bridge_addr = opt_address("--bridge", o.bridge);
    target_model m;
    load_model(o.model, &m);
    const int na = m.axes;
    int most = (int)ambp_max_block((unsigned)na, o.float32 ? 4u : 8u, (unsigned)o.version);
    if (o.block > most)
        die2("option --block = %d: at most %d samples of %d axes fit one datagram at %s", o.block, most, na,
             o.float32 ? "float32" : "float64");
    if (o.version == 1 && na != (int)AMBP_V1_AXES)
        die2("--protocol-version 1 carries %u axes, the model file has %d; speak version 2", AMBP_V1_AXES, na);
    uint8_t key[AMBP_MAX_KEY_BYTES];
    size_t key_len = o.key_file ? load_key(o.key_file, key) : 0;
    char fingerprint[17] = "";
    if (key_len) ambp_key_fingerprint(key, key_len, fingerprint);
    if (o.priority) { /* Linux-RT style: locked memory, SCHED_FIFO; the loop sleeps between samples */
        struct sched_param sp;
        memset(&sp, 0, sizeof sp);
        sp.sched_priority = o.priority;
        if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0 || sched_setscheduler(0, SCHED_FIFO, &sp) != 0)
            die2("--priority %d: cannot lock memory and run at SCHED_FIFO priority (%s); run as root or with "
                 "CAP_SYS_NICE and CAP_IPC_LOCK, or leave --priority out", o.priority, strerror(errno));
    }

    uint32_t rate_hz = (uint32_t)floor(1.0 / m.dt + 0.5);
    ambp_config cfg;
    ambp_default_config(&cfg, rate_hz, (uint8_t)na);
    cfg.version = (uint8_t)o.version;
    cfg.value_bytes = o.float32 ? 4 : 8;
    if (o.block) cfg.block = (uint16_t)o.block;
    cfg.heartbeat_ns = (uint64_t)(o.heartbeat * 1e9);
    cfg.bridge_timeout_ns = (uint64_t)(o.bridge_timeout * 1e9);
    cfg.safe_samples = (uint64_t)floor(o.safe_seconds / m.dt + 0.5);
    cfg.max_samples = (uint64_t)o.samples;
    cfg.hold_for_excitation = o.hold;
    /* the state is static, as an embedded build has it; the queue is sized by --queue, so it is allocated
     * once here (the core itself never allocates) */
    static ambp_target t;
    ambp_exc_slot *queue = malloc(sizeof(ambp_exc_slot) * (size_t)o.queue);
    if (!queue) die2("out of memory for an excitation queue of %d samples; use a smaller --queue", o.queue);

    int fd = socket(AF_INET, SOCK_DGRAM, 0);
    if (fd < 0) die2("cannot open a UDP socket: %s", strerror(errno));
    int rcv = 4 * 1024 * 1024;
    setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &rcv, sizeof rcv);
    if (bind(fd, (struct sockaddr *)&bind_addr, sizeof bind_addr) != 0)
        die2("cannot bind --bind %s: %s; choose a free port", o.bind, strerror(errno));
    struct sockaddr_in bound;
    socklen_t blen = sizeof bound;
    getsockname(fd, (struct sockaddr *)&bound, &blen);
    char host[INET_ADDRSTRLEN];
    inet_ntop(AF_INET, &bound.sin_addr, host, sizeof host);
    printf("RT_TARGET_LISTENING %s:%u\n", host, (unsigned)ntohs(bound.sin_port));
    fflush(stdout);
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);

    uint64_t t_now = now_ns();
    if (ambp_target_init(&t, &cfg, queue, (uint32_t)o.queue, t_now) != 0) die2("invalid protocol configuration");
    if (key_len) {
        uint8_t seed[32];
        random_seed(seed);
        if (ambp_target_set_key(&t, key, key_len, seed) != 0) die2("the key does not fit protocol version %d", o.version);
        ambp_wipe(key, sizeof key); /* the core holds the key's HMAC pads only */
        ambp_wipe(seed, sizeof seed);
        fprintf(stderr, "ambp_udp_target: protocol version %d, authenticated with the key of fingerprint %s\n",
                o.version, fingerprint);
    } else {
        fprintf(stderr, "ambp_udp_target: the link is unauthenticated (protocol version %d): any host on the rig "
                "network can command the magnets; use protocol version 3 with --key-file\n", o.version);
    }
    rng_state = (uint64_t)o.seed;

    int np = m.plant.n, nc = m.ctl.n;
    double *xp = calloc((size_t)np + 1, sizeof(double)), *xp2 = calloc((size_t)np + 1, sizeof(double));
    double *xc = calloc((size_t)nc + 1, sizeof(double)), *xc2 = calloc((size_t)nc + 1, sizeof(double));
    if (!xp || !xp2 || !xc || !xc2) die2("out of memory for the model states");

    const uint64_t period_ns = (uint64_t)floor(m.dt * o.pace * 1e9 + 0.5);
    uint64_t t_start = 0, k_start = 0, halted_at = 0, late_samples = 0, max_late_ns = 0, wall0 = 0;
    uint64_t wall_end = 0;
    int was_running = 0, behind = 0, halted = 0;
    uint8_t buf[2048];

    while (!g_stop) {
        /* everything that arrived */
        for (;;) {
            struct sockaddr_in from;
            socklen_t flen = sizeof from;
            ssize_t n = recvfrom(fd, buf, sizeof buf, MSG_DONTWAIT, (struct sockaddr *)&from, &flen);
            if (n < 0) break; /* EAGAIN, or an ICMP error reported on the socket */
            int ours = from.sin_addr.s_addr == bridge_addr.sin_addr.s_addr && from.sin_port == bridge_addr.sin_port;
            ambp_target_receive(&t, buf, (size_t)n, ours, now_ns());
        }
        t_now = now_ns();
        ambp_target_poll(&t, t_now);
        if (t.clock_running && !was_running) {
            t_start = t_now;
            k_start = t.k;
            wall0 = t_now;
        }
        if (t.stop_requested) break; /* STOP answered: leave once its ACK is out (below) */

        int burst = t.clock_running ? (o.pace == 0 ? FREE_RUN_POLL : 1) : 0;
        for (int s = 0; s < burst; s++) {
            if (o.pace > 0) {
                /* sample k is due at t_start + (k - k_start) period: sleep to that absolute deadline */
                uint64_t due = t_start + (t.k - k_start) * period_ns;
                struct timespec ts = {(time_t)(due / 1000000000ull), (long)(due % 1000000000ull)};
                while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, NULL) == EINTR && !g_stop) {}
                uint64_t late = now_ns() - due;
                if (late > max_late_ns) max_late_ns = late;
                if (late > period_ns) late_samples++;
                int lagging = late > LAG_OVERRUN_NS; /* wall time behind, as the Python target counts it */
                if (lagging && !behind) ambp_target_count_overrun(&t);
                behind = lagging;
            }
            double r[AMBP_MAX_AXES], y[AMBP_MAX_AXES], ic[AMBP_MAX_AXES], u[AMBP_MAX_AXES], ua[AMBP_MAX_AXES];
            uint8_t flags;
            int action = ambp_target_sample_begin(&t, r, &flags);
            if (action == AMBP_SAMPLE_HOLD) {
                struct pollfd pfd = {fd, POLLIN, 0};
                poll(&pfd, 1, 1); /* wait (at most 1 ms) for the excitation */
                break;
            }
            if (action == AMBP_SAMPLE_STOPPED) break;
            /* y[k] = C x[k] + noise; ic[k] = controller(y[k]); u = ic + r held over the next period */
            matvec(m.plant.c, xp, y, na, np, 0);
            for (int i = 0; i < na; i++) y[i] += m.noise_std[i] * normal();
            if (action == AMBP_SAMPLE_CONTROL) {
                matvec(m.ctl.c, xc, ic, na, nc, 0);
                matvec(m.ctl.d, y, ic, na, na, 1);
                matvec(m.ctl.a, xc, xc2, nc, nc, 0);
                matvec(m.ctl.b, y, xc2, nc, na, 1);
                memcpy(xc, xc2, sizeof(double) * (size_t)nc);
                for (int i = 0; i < na; i++) ic[i] = fmax(-m.controller_limit, fmin(m.controller_limit, ic[i]));
            } else {
                for (int i = 0; i < na; i++) ic[i] = 0.0;
            }
            for (int i = 0; i < na; i++) {
                u[i] = ic[i] + r[i];
                ua[i] = fmax(-m.current_limit, fmin(m.current_limit, u[i]));
                if (ua[i] != u[i]) flags |= AMBP_FLAG_CLIPPED;
            }
            matvec(m.plant.a, xp, xp2, np, np, 0);
            matvec(m.plant.b, ua, xp2, np, na, 1);
            memcpy(xp, xp2, sizeof(double) * (size_t)np);
            ambp_target_sample_end(&t, y, u, ic, r, flags, o.pace > 0 ? now_ns() : t_now);
            if (!t.clock_running) break;
            const uint8_t *d;
            size_t len;
            while (ambp_target_tx(&t, &d, &len))
                sendto(fd, d, len, 0, (struct sockaddr *)&bridge_addr, sizeof bridge_addr);
        }
        if (!t.clock_running && was_running) { halted = 1; halted_at = now_ns(); wall_end = halted_at; }
        if (!t.clock_running && t.state != AMBP_IDLE && !halted) { halted = 1; halted_at = now_ns(); }
        was_running = t.clock_running;
        const uint8_t *d;
        size_t len;
        while (ambp_target_tx(&t, &d, &len))
            sendto(fd, d, len, 0, (struct sockaddr *)&bridge_addr, sizeof bridge_addr);
        if (!t.clock_running) {
            t_now = now_ns();
            if (halted && o.linger > 0 && t_now - halted_at > (uint64_t)(o.linger * 1e9)) break;
            int64_t wait_ns = (int64_t)(t.next_hb_ns - t_now);
            if (wait_ns > 10000000) wait_ns = 10000000;
            if (wait_ns > 0) {
                struct pollfd pfd = {fd, POLLIN, 0};
                poll(&pfd, 1, (int)(wait_ns / 1000000) + 1);
            }
        }
    }
    const uint8_t *d;
    size_t len;
    while (ambp_target_tx(&t, &d, &len))
        sendto(fd, d, len, 0, (struct sockaddr *)&bridge_addr, sizeof bridge_addr);
    if (!wall_end) wall_end = now_ns();
    close(fd);
    static const char *const states[] = {"idle", "running", "safe", "done"};
    static const char *const reasons[] = {"none", "commanded", "bridge_silent"};
    double wall = wall0 ? (double)(wall_end - wall0) * 1e-9 : 0.0;
    printf("RT_TARGET_SUMMARY {\"implementation\": \"c\", \"state\": \"%s\", \"safe_reason\": \"%s\", "
           "\"samples\": %llu, \"sent_end\": %llu, \"wall_s\": %.6f, \"samples_per_wall_s\": %.1f, "
           "\"commanded_samples_per_s\": %.1f, \"late_samples\": %llu, \"max_late_us\": %.1f, \"overruns\": %u, "
           "\"rx_datagrams\": %u, \"rx_foreign\": %u, \"rx_malformed\": %u, \"rx_rejected_by_reason\": {",
           states[t.state & 3], reasons[t.safe_reason % 3], (unsigned long long)t.k,
           (unsigned long long)t.sent_end, wall, wall > 0 ? (double)t.k / wall : 0.0,
           o.pace > 0 ? rate_hz / o.pace : 0.0, (unsigned long long)late_samples, (double)max_late_ns * 1e-3,
           t.overruns, t.rx, t.rx_rejected_by_reason[AMBP_E_FOREIGN],
           ambp_target_rx_rejected(&t) - t.rx_rejected_by_reason[AMBP_E_FOREIGN]);
    for (int i = 1; i < AMBP_N_REASONS; i++)
        printf("%s\"%s\": %u", i > 1 ? ", " : "", ambp_reason_name(i), t.rx_rejected_by_reason[i]);
    printf("}, \"late_excitation_samples\": %u, \"late_excitation_datagrams\": %u, "
           "\"excitation_beyond_queue\": %u, \"tx_dropped\": %u, \"seed\": %lld, \"protocol_version\": %d, "
           "\"authenticated\": %s, \"key_fingerprint\": \"%s\", \"session\": \"",
           t.late_excitation, t.excitation_late_datagrams, t.excitation_beyond_queue, t.tx_dropped, o.seed, o.version,
           key_len ? "true" : "false", fingerprint);
    if (key_len && t.agreed)
        for (unsigned i = 0; i < AMBP_SESSION_BYTES; i++) printf("%02x", t.session[i]);
    printf("\"}\n");
    fflush(stdout);
    return t.state == AMBP_DONE ? 0 : 1;
}
