/* ambp: the target side of the ambid bridge protocol, versions 3, 2 and 1 (docs/bridge_protocol.md), in C99.
 *
 * Portable core: no heap, no OS calls, no globals that change. The caller owns every byte: one
 * ambp_target struct of state, the excitation queue's storage, and the clock (monotonic
 * nanoseconds passed in). It fits a Simulink S-function, a Speedgoat model or a microcontroller;
 * the POSIX UDP program ambp_udp_target.c is one caller. See docs/target_c.md.
 *
 * Version 3 authenticates every datagram with the rig's key (HMAC-SHA-256, ambp_hmac.h) and binds it to a
 * session agreed by a HELLO / WELCOME handshake: call ambp_target_set_key after ambp_target_init.
 *
 * A caller's loop, per sample k:
 *     ambp_target_receive()  for each datagram that arrived (from_bridge: its source is the bridge)
 *     ambp_target_poll()     heartbeat due? bridge silent?
 *     ambp_target_sample_begin() -> r[k] and the flags; run the controller (or not, in the safe state)
 *     ambp_target_sample_end()   with y, u, ic, r of sample k
 *     while (ambp_target_tx()) send the datagram to the bridge
 */
#ifndef AMBP_H
#define AMBP_H

#include <stddef.h>
#include <stdint.h>

#include "ambp_hmac.h"

#ifdef __cplusplus
extern "C" {
#endif

#define AMBP_VERSION 3u               /* the default: version 3, authenticated; 2: any number of axes, unsealed;
                                       * 1: four axes */
#define AMBP_AUTH_VERSION 3u          /* version 3 and later: sealed (sender, session id, tag) */
#define AMBP_V1_AXES 4u               /* version 1's channel sets carry exactly four axes */
#define AMBP_MAX_AXES 8u
#define AMBP_MAX_DATAGRAM 1472u       /* 1500-byte MTU minus IPv4 and UDP headers */
#define AMBP_HEADER_BYTES 16u
#define AMBP_OVERHEAD_BYTES 20u       /* header + CRC-32 trailer */
#define AMBP_HEADER_V3_BYTES 24u      /* version 3: ... sender, reserved, ..., session id */
#define AMBP_OVERHEAD_V3_BYTES 44u    /* version 3: header + tag + CRC-32 */
#define AMBP_TAG_BYTES 16u            /* HMAC-SHA-256 truncated to 128 bits */
#define AMBP_SESSION_BYTES 8u
#define AMBP_NONCE_BYTES 16u
#define AMBP_MIN_KEY_BYTES 16u
#define AMBP_MAX_KEY_BYTES 64u
#define AMBP_WINDOW 64u               /* sequence numbers per kind remembered below the highest accepted */
#define AMBP_PROPOSALS 4u             /* sessions proposed (WELCOME sent) and not yet confirmed */
#define AMBP_BLOCK_HEADER_BYTES 16u
#define AMBP_NO_INDEX UINT64_MAX
#define AMBP_MAX_MEAS_SAMPLES 84u     /* one axis at float32: (1472 - 36) / (4 * 4 + 1) */
#define AMBP_MAX_VALUES 359u          /* most sample values one block datagram carries: (1472 - 36) / 4 at float32 */
#define AMBP_MAX_EXPERIMENTS 16u      /* announced ranges held at once */
#define AMBP_ACK_MEMORY 64u           /* command ids remembered, so a repeated command gets its first answer */
#define AMBP_OUTBOX 8u                /* datagrams waiting for ambp_target_tx */

enum ambp_kind {
    AMBP_MEASUREMENT = 1, AMBP_EXCITATION = 2, AMBP_HEARTBEAT = 3, AMBP_COMMAND = 4, AMBP_ACK = 5,
    AMBP_HELLO = 6, AMBP_WELCOME = 7 /* version 3 */
};
enum ambp_sender { AMBP_SENDER_BRIDGE = 1, AMBP_SENDER_TARGET = 2 };
enum ambp_state { AMBP_IDLE = 0, AMBP_RUNNING = 1, AMBP_SAFE = 2, AMBP_DONE = 3 };
enum ambp_safe_reason { AMBP_SAFE_NONE = 0, AMBP_SAFE_COMMANDED = 1, AMBP_SAFE_BRIDGE_SILENT = 2 };
enum ambp_command_code { AMBP_CMD_START = 1, AMBP_CMD_STOP = 2, AMBP_CMD_SAFE_STATE = 3, AMBP_CMD_EXPERIMENT = 4 };
enum ambp_ack_result { AMBP_ACK_OK = 0, AMBP_ACK_REFUSED = 1, AMBP_ACK_BAD_ARGUMENT = 2 };
enum ambp_sample_flag {
    AMBP_FLAG_CLIPPED = 1, AMBP_FLAG_LANDED = 2, AMBP_FLAG_SAFE_STATE = 8, AMBP_FLAG_EXCITATION_LATE = 16
};
/* why a datagram was refused (0: accepted); AUTH and the ones after it are version 3's */
enum ambp_reason {
    AMBP_OK = 0, AMBP_E_OVERSIZED, AMBP_E_LENGTH, AMBP_E_MAGIC, AMBP_E_VERSION, AMBP_E_CRC, AMBP_E_KIND,
    AMBP_E_CONTENT, AMBP_E_FOREIGN,
    AMBP_E_AUTH,      /* the tag is not the rig key's: forged, or another key */
    AMBP_E_DIRECTION, /* sealed by this end's own role, or a kind the bridge never sends: reflected */
    AMBP_E_SESSION,   /* of another session (or a HELLO once the session is agreed) */
    AMBP_E_REPLAY,    /* a sequence older than the replay window */
    AMBP_E_DUPLICATE, /* a sequence accepted before */
    AMBP_N_REASONS
};
/* what the caller does with sample k (ambp_target_sample_begin) */
enum ambp_sample_action {
    AMBP_SAMPLE_STOPPED = 0, /* the clock does not run: no sample */
    AMBP_SAMPLE_CONTROL = 1, /* run the controller, apply u = ic + r */
    AMBP_SAMPLE_SAFE = 2,    /* safe state: ic = r = u = 0, the controller is not applied */
    AMBP_SAMPLE_HOLD = 3     /* hold_for_excitation: r[k] has not arrived; try again later, no sample */
};

/* One decoded (or to be encoded) datagram; the fields of its kind are used, the rest ignored. */
typedef struct {
    uint8_t kind;                      /* enum ambp_kind */
    uint8_t value_bytes;               /* block kinds: 8 (float64) or 4 (float32) */
    uint8_t axes;                      /* block kinds: axes na (channels 4 na MEASUREMENT, na EXCITATION);
                                        * HEARTBEAT (version 2): the sender's axes */
    uint16_t n_samples;                /* block kinds */
    uint32_t sequence;
    uint64_t first_index;              /* block kinds */
    /* HEARTBEAT; ACK uses state and sample_index too */
    uint8_t state, safe_reason, clock_running, reserved0;
    uint32_t sample_rate_hz;
    uint64_t sample_index, sent_end, excitation_next;
    uint32_t next_measurement_sequence, rx_datagrams, rx_rejected, late_excitation_samples, overruns;
    /* COMMAND and ACK */
    uint32_t command_id;
    uint8_t code, result, reserved1, reserved2;
    uint64_t arg0, arg1;
    uint32_t arg2, reserved3;
    /* block data, row-major n_samples x channels (4 na MEASUREMENT, na EXCITATION), and sample flags */
    double data[AMBP_MAX_VALUES];
    uint8_t sample_flags[AMBP_MAX_MEAS_SAMPLES];
    /* version 3: the header's sender (enum ambp_sender) and session id; HELLO and WELCOME's nonces; the
     * HEARTBEAT's refusals by reason */
    uint8_t sender;
    uint8_t session[AMBP_SESSION_BYTES];
    uint8_t bridge_nonce[AMBP_NONCE_BYTES], target_nonce[AMBP_NONCE_BYTES];
    uint32_t refused_auth, refused_session, refused_replay, duplicates;
} ambp_message;

uint32_t ambp_crc32(const uint8_t *data, size_t n);

/* The datagram of m (version in the header) into out[cap]; returns its length, 0 when m is invalid
 * (unknown kind or one the version lacks, n_samples 0 or too many, value_bytes not 4 or 8, NaN/Inf data),
 * cap too small, or version 3 without a key. Version 3 seals it with key, m->sender and m->session. */
size_t ambp_encode(const ambp_message *m, uint8_t version, const ambp_hmac_key *key, uint8_t *out, size_t cap);

/* The message in datagram d[n] (checks in the protocol's order; version 3 checks the tag under key);
 * returns AMBP_OK or the reason. What depends on the link's state (sender, session, replay window) is the
 * target's (ambp_target_receive). */
int ambp_decode(const uint8_t *d, size_t n, uint8_t version, const ambp_hmac_key *key, ambp_message *m);

const char *ambp_reason_name(int reason);

/* the key's fingerprint: 16 hex digits of SHA-256("ambid link key\0" | key) and a NUL; the key never shows */
void ambp_key_fingerprint(const uint8_t *key, size_t n, char out[17]);

/* the session id both ends derive from the handshake's nonces: HMAC-SHA-256(key, label | nb | nt)[:8] */
void ambp_session_id(const ambp_hmac_key *key, const uint8_t nb[AMBP_NONCE_BYTES],
                     const uint8_t nt[AMBP_NONCE_BYTES], uint8_t out[AMBP_SESSION_BYTES]);

/* excitation queue slot: r [A] of the sample `index` (AMBP_NO_INDEX: empty), the first axes values used */
typedef struct {
    uint64_t index;
    double r[AMBP_MAX_AXES];
} ambp_exc_slot;

typedef struct {
    uint8_t version;            /* protocol version spoken: 2, or 1 (four axes only) */
    uint8_t axes;               /* axes na the target runs, 1..AMBP_MAX_AXES, in the rig's channel order */
    uint8_t value_bytes;        /* MEASUREMENT values: 8 or 4 */
    uint16_t block;             /* samples per MEASUREMENT datagram: at most (1436) / (4 na value_bytes + 1),
                                 * e.g. 11 (float64) or 22 (float32) of four axes, 8 or 17 of five */
    uint32_t sample_rate_hz;    /* control rate, reported in the heartbeat */
    uint64_t heartbeat_ns;      /* heartbeat period */
    uint64_t bridge_timeout_ns; /* bridge silence while RUNNING -> safe state */
    uint64_t safe_samples;      /* samples of landing in the safe state before the clock stops */
    uint64_t max_samples;       /* DONE after this many samples; 0 = until STOP */
    int hold_for_excitation;    /* free-running callers only: wait for missing excitation instead of r = 0 */
} ambp_config;

typedef struct {
    ambp_config cfg;
    ambp_exc_slot *exc;          /* caller's storage: sample i lives in exc[i % exc_capacity] */
    uint32_t exc_capacity;
    uint8_t state, safe_reason, clock_running, stop_requested;
    uint64_t k;                  /* samples done = the next sample index */
    uint64_t sent_end;
    uint32_t seq[6];             /* next sequence per kind */
    /* counters */
    uint32_t rx, rx_rejected_by_reason[AMBP_N_REASONS], rx_unexpected_kind;
    uint32_t late_excitation, overruns, excitation_late_datagrams, excitation_beyond_queue, tx_dropped;
    /* announced experiments: slot id -> [start, end) */
    uint32_t range_slot[AMBP_MAX_EXPERIMENTS];
    uint64_t range_start[AMBP_MAX_EXPERIMENTS], range_end[AMBP_MAX_EXPERIMENTS];
    uint8_t range_used[AMBP_MAX_EXPERIMENTS];
    /* answered commands */
    uint32_t ack_id[AMBP_ACK_MEMORY];
    uint8_t ack_result[AMBP_ACK_MEMORY], ack_used[AMBP_ACK_MEMORY];
    uint32_t ack_next;
    /* timing */
    int heard;
    uint64_t last_rx_ns, next_hb_ns, safe_left;
    /* version 3: the key, the nonces' seed and count, the session proposed and agreed, the replay windows */
    int keyed, agreed;
    ambp_hmac_key key;
    uint8_t nonce_seed[32];
    uint64_t nonces;
    uint8_t session[AMBP_SESSION_BYTES], agreed_bridge_nonce[AMBP_NONCE_BYTES];
    uint8_t prop_used[AMBP_PROPOSALS], prop_session[AMBP_PROPOSALS][AMBP_SESSION_BYTES];
    uint8_t prop_nb[AMBP_PROPOSALS][AMBP_NONCE_BYTES], prop_nt[AMBP_PROPOSALS][AMBP_NONCE_BYTES];
    uint32_t prop_next;
    uint32_t win_top[8];
    uint64_t win_bits[8];        /* bit i: win_top - i accepted; 0: nothing accepted of that kind yet */
    /* the MEASUREMENT datagram being filled: rows of y, u, ic, r (na each) */
    double rows[AMBP_MAX_VALUES];
    uint8_t row_flags[AMBP_MAX_MEAS_SAMPLES];
    uint16_t n_rows;
    /* datagrams to send, in order */
    uint8_t out[AMBP_OUTBOX][AMBP_MAX_DATAGRAM];
    uint16_t out_len[AMBP_OUTBOX];
    uint32_t out_head, out_count;
    ambp_message scratch;        /* decode and encode buffer: nothing large on the caller's stack */
} ambp_target;

/* Defaults of the protocol document: version AMBP_VERSION, float64, heartbeat 50 ms, timeout 0.5 s, and the
 * largest block of na axes up to 10 samples. */
void ambp_default_config(ambp_config *cfg, uint32_t sample_rate_hz, uint8_t axes);

/* Most samples one MEASUREMENT datagram of na axes carries at value_bytes 8 or 4 and the version's
 * overhead (0: none fits). */
unsigned ambp_max_block(unsigned axes, unsigned value_bytes, unsigned version);

/* Returns 0, or -1 when cfg is invalid (axes out of range or not 4 in version 1, block out of range,
 * value_bytes, rate 0, capacity 0). The queue holds excitation for samples [k, k + capacity): more than
 * the bridge sends ahead. */
int ambp_target_init(ambp_target *t, const ambp_config *cfg, ambp_exc_slot *storage, uint32_t capacity,
                     uint64_t now_ns);

/* Version 3 (cfg.version 3): the rig's key (AMBP_MIN_KEY_BYTES..AMBP_MAX_KEY_BYTES) and 32 bytes of seed
 * that differ at every start (e.g. from the OS's random source or a hardware RNG): the target's session
 * nonces are HMAC(key, label | seed | count), so a seed used twice would let an old session be replayed.
 * Call after ambp_target_init. Returns 0, or -1 (not version 3, or a key of another length). Until a
 * session is agreed the target sends nothing but WELCOMEs. */
int ambp_target_set_key(ambp_target *t, const uint8_t *key, size_t n, const uint8_t seed[32]);

/* One received datagram. from_bridge = 0: another sender, dropped and counted. Returns the reason
 * it was refused, or AMBP_OK. */
int ambp_target_receive(ambp_target *t, const uint8_t *d, size_t n, int from_bridge, uint64_t now_ns);

/* Time-driven work: the safe state when the bridge is silent, the periodic heartbeat. */
void ambp_target_poll(ambp_target *t, uint64_t now_ns);

/* Sample k = t->k: r[na] to apply and flags (AMBP_FLAG_SAFE_STATE, AMBP_FLAG_EXCITATION_LATE). */
int ambp_target_sample_begin(ambp_target *t, double *r, uint8_t *flags);

/* Sample k is done: its row (y, u, ic, r: na values each) and flags (those of sample_begin OR
 * CLIPPED/LANDED of the plant). */
void ambp_target_sample_end(ambp_target *t, const double *y, const double *u, const double *ic,
                            const double *r, uint8_t flags, uint64_t now_ns);

/* The next datagram to send (valid until the next call into the core); 0 when none is waiting. */
int ambp_target_tx(ambp_target *t, const uint8_t **data, size_t *len);

/* The caller's schedule fell more than 10 ms behind (counted, reported in the heartbeat). */
void ambp_target_count_overrun(ambp_target *t);

/* First announced sample >= k without excitation, within the queue's window; AMBP_NO_INDEX if none. */
uint64_t ambp_target_excitation_next(const ambp_target *t);

uint32_t ambp_target_rx_rejected(const ambp_target *t);

#ifdef __cplusplus
}
#endif
#endif
