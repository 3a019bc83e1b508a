/* ambp: the target side of the ambid bridge protocol, versions 3, 2 and 1. See ambp.h and
 * docs/bridge_protocol.md.
 * C99, no heap, no OS calls; byte order written explicitly, so it runs on big-endian targets too. */
#include "ambp.h"

#include <math.h>
#include <string.h>

/* ---- little-endian fields ------------------------------------------------------------------- */
static void put16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static void put64(uint8_t *p, uint64_t v) { for (int i = 0; i < 8; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static uint16_t get16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static uint64_t get64(const uint8_t *p) { return (uint64_t)get32(p) | ((uint64_t)get32(p + 4) << 32); }
static void put_f64(uint8_t *p, double v) { uint64_t u; memcpy(&u, &v, 8); put64(p, u); }
static void put_f32(uint8_t *p, double v) { float f = (float)v; uint32_t u; memcpy(&u, &f, 4); put32(p, u); }
static double get_f64(const uint8_t *p) { uint64_t u = get64(p); double v; memcpy(&v, &u, 8); return v; }
static double get_f32(const uint8_t *p) { uint32_t u = get32(p); float f; memcpy(&f, &u, 4); return (double)f; }

/* ---- CRC-32 (IEEE 802.3, reflected 0xEDB88320, as zlib.crc32), a 16-entry table: small and fast enough */
static const uint32_t crc_nibble[16] = {
    0x00000000u, 0x1DB71064u, 0x3B6E20C8u, 0x26D930ACu, 0x76DC4190u, 0x6B6B51F4u, 0x4DB26158u, 0x5005713Cu,
    0xEDB88320u, 0xF00F9344u, 0xD6D6A3E8u, 0xCB61B38Cu, 0x9B64C2B0u, 0x86D3D2D4u, 0xA00AE278u, 0xBDBDF21Cu};

uint32_t ambp_crc32(const uint8_t *data, size_t n) {
    uint32_t c = 0xFFFFFFFFu;
    for (size_t i = 0; i < n; i++) {
        c ^= data[i];
        c = (c >> 4) ^ crc_nibble[c & 15u];
        c = (c >> 4) ^ crc_nibble[c & 15u];
    }
    return c ^ 0xFFFFFFFFu;
}

static const char *const reason_names[AMBP_N_REASONS] = {
    "ok", "oversized", "length", "magic", "version", "crc", "kind", "content", "foreign",
    "auth", "direction", "session", "replay", "duplicate"};

const char *ambp_reason_name(int reason) {
    return (reason >= 0 && reason < AMBP_N_REASONS) ? reason_names[reason] : "unknown";
}

/* ---- codec ----------------------------------------------------------------------------------- */
/* a block's channels: y, u, ic, r of every axis (MEASUREMENT), r of every axis (EXCITATION) */
static unsigned block_channels(int kind, unsigned axes) { return kind == AMBP_MEASUREMENT ? 4u * axes : axes; }
/* version 1's block field at offset 12: the channel set (1 measurement, 2 excitation); version 2's: the axes */
static unsigned block_channel_set(int kind) { return kind == AMBP_MEASUREMENT ? 1u : 2u; }

static int axes_valid(unsigned axes, uint8_t version) {
    return version == 1 ? axes == AMBP_V1_AXES : axes >= 1 && axes <= AMBP_MAX_AXES;
}

static unsigned overhead(unsigned version) {
    return version >= AMBP_AUTH_VERSION ? AMBP_OVERHEAD_V3_BYTES : AMBP_OVERHEAD_BYTES;
}
static unsigned header_bytes(unsigned version) {
    return version >= AMBP_AUTH_VERSION ? AMBP_HEADER_V3_BYTES : AMBP_HEADER_BYTES;
}

unsigned ambp_max_block(unsigned axes, unsigned value_bytes, unsigned version) {
    if (axes < 1 || axes > AMBP_MAX_AXES || (value_bytes != 8 && value_bytes != 4)) return 0;
    unsigned most = (AMBP_MAX_DATAGRAM - overhead(version) - AMBP_BLOCK_HEADER_BYTES) / (4u * axes * value_bytes + 1u);
    return most < AMBP_MAX_MEAS_SAMPLES ? most : AMBP_MAX_MEAS_SAMPLES;
}

static size_t payload_size(const ambp_message *m, uint8_t version) {
    switch (m->kind) {
    case AMBP_MEASUREMENT:
    case AMBP_EXCITATION: {
        size_t per = (size_t)block_channels(m->kind, m->axes) * m->value_bytes +
                     (m->kind == AMBP_MEASUREMENT ? 1u : 0u);
        return AMBP_BLOCK_HEADER_BYTES + (size_t)m->n_samples * per;
    }
    case AMBP_HEARTBEAT: return version >= AMBP_AUTH_VERSION ? 72 : 56;
    case AMBP_COMMAND: return 32;
    case AMBP_ACK: return 16;
    case AMBP_HELLO: return version >= AMBP_AUTH_VERSION ? AMBP_NONCE_BYTES : 0;
    case AMBP_WELCOME: return version >= AMBP_AUTH_VERSION ? 2 * AMBP_NONCE_BYTES : 0;
    default: return 0;
    }
}

size_t ambp_encode(const ambp_message *m, uint8_t version, const ambp_hmac_key *key, uint8_t *out, size_t cap) {
    size_t pl = payload_size(m, version);
    const int sealed = version >= AMBP_AUTH_VERSION;
    if (pl == 0 || (sealed && (key == NULL || (m->sender != AMBP_SENDER_BRIDGE && m->sender != AMBP_SENDER_TARGET))))
        return 0;
    int block = m->kind == AMBP_MEASUREMENT || m->kind == AMBP_EXCITATION;
    if (block) {
        size_t nv = (size_t)m->n_samples * block_channels(m->kind, m->axes);
        if (!axes_valid(m->axes, version) || (m->value_bytes != 8 && m->value_bytes != 4) || m->n_samples == 0 ||
            nv > AMBP_MAX_VALUES || (m->kind == AMBP_MEASUREMENT && m->n_samples > AMBP_MAX_MEAS_SAMPLES))
            return 0;
        for (size_t i = 0; i < nv; i++)
            if (!isfinite(m->data[i])) return 0;
    }
    const size_t hb = header_bytes(version);
    size_t size = overhead(version) + pl;
    if (size > AMBP_MAX_DATAGRAM || size > cap) return 0;
    memcpy(out, "AMBP", 4);
    out[4] = version;
    out[5] = m->kind;
    put16(out + 6, 0);
    if (sealed) out[6] = m->sender;
    put32(out + 8, m->sequence);
    put16(out + 12, (uint16_t)pl);
    put16(out + 14, 0);
    if (sealed) memcpy(out + 16, m->session, AMBP_SESSION_BYTES);
    uint8_t *p = out + hb;
    memset(p, 0, pl);
    switch (m->kind) {
    case AMBP_MEASUREMENT:
    case AMBP_EXCITATION: {
        unsigned nch = block_channels(m->kind, m->axes);
        put64(p, m->first_index);
        put16(p + 8, m->n_samples);
        put16(p + 10, (uint16_t)nch);
        put16(p + 12, (uint16_t)(version == 1 ? block_channel_set(m->kind) : m->axes));
        p[14] = m->value_bytes;
        size_t nv = (size_t)m->n_samples * nch;
        uint8_t *v = p + AMBP_BLOCK_HEADER_BYTES;
        for (size_t i = 0; i < nv; i++) {
            if (m->value_bytes == 8) put_f64(v + 8 * i, m->data[i]);
            else put_f32(v + 4 * i, m->data[i]);
        }
        if (m->kind == AMBP_MEASUREMENT) memcpy(v + nv * m->value_bytes, m->sample_flags, m->n_samples);
        break;
    }
    case AMBP_HEARTBEAT:
        p[0] = m->state; p[1] = m->safe_reason; p[2] = m->clock_running ? 1 : 0;
        p[3] = version == 1 ? 0 : m->axes;
        put32(p + 4, m->sample_rate_hz);
        put64(p + 8, m->sample_index); put64(p + 16, m->sent_end); put64(p + 24, m->excitation_next);
        put32(p + 32, m->next_measurement_sequence); put32(p + 36, m->rx_datagrams);
        put32(p + 40, m->rx_rejected); put32(p + 44, m->late_excitation_samples); put32(p + 48, m->overruns);
        if (sealed) {
            put32(p + 56, m->refused_auth); put32(p + 60, m->refused_session);
            put32(p + 64, m->refused_replay); put32(p + 68, m->duplicates);
        }
        break;
    case AMBP_COMMAND:
        put32(p, m->command_id); p[4] = m->code;
        put64(p + 8, m->arg0); put64(p + 16, m->arg1); put32(p + 24, m->arg2);
        break;
    case AMBP_ACK:
        put32(p, m->command_id); p[4] = m->code; p[5] = m->result; p[6] = m->state;
        put64(p + 8, m->sample_index);
        break;
    case AMBP_HELLO:
        memcpy(p, m->bridge_nonce, AMBP_NONCE_BYTES);
        break;
    case AMBP_WELCOME:
        memcpy(p, m->bridge_nonce, AMBP_NONCE_BYTES);
        memcpy(p + AMBP_NONCE_BYTES, m->target_nonce, AMBP_NONCE_BYTES);
        break;
    }
    size_t body = hb + pl;
    if (sealed) {
        uint8_t tag[AMBP_SHA256_BYTES];
        ambp_hmac(key, out, body, tag);
        memcpy(out + body, tag, AMBP_TAG_BYTES);
        body += AMBP_TAG_BYTES;
    }
    put32(out + body, ambp_crc32(out, body));
    return size;
}

static int decode_block(const uint8_t *p, size_t pl, uint8_t version, ambp_message *m) {
    if (pl < AMBP_BLOCK_HEADER_BYTES) return AMBP_E_LENGTH;
    uint64_t first = get64(p);
    uint16_t n = get16(p + 8), nch = get16(p + 10), set = get16(p + 12);
    uint8_t vb = p[14];
    unsigned axes = version == 1 ? (set == block_channel_set(m->kind) ? AMBP_V1_AXES : 0u) : set;
    if (!axes_valid(axes, version) || nch != block_channels(m->kind, axes)) return AMBP_E_CONTENT;
    if (vb != 8 && vb != 4) return AMBP_E_CONTENT;
    if (n < 1) return AMBP_E_CONTENT;
    size_t n_flags = m->kind == AMBP_MEASUREMENT ? n : 0;
    size_t want = AMBP_BLOCK_HEADER_BYTES + (size_t)n * nch * vb + n_flags;
    if (pl != want) return AMBP_E_LENGTH;
    /* a datagram within 1472 bytes cannot hold more values than the arrays take */
    size_t nv = (size_t)n * nch;
    const uint8_t *v = p + AMBP_BLOCK_HEADER_BYTES;
    for (size_t i = 0; i < nv; i++) {
        double x = vb == 8 ? get_f64(v + 8 * i) : get_f32(v + 4 * i);
        if (!isfinite(x)) return AMBP_E_CONTENT;
        m->data[i] = x;
    }
    if (n_flags) memcpy(m->sample_flags, v + nv * vb, n_flags);
    m->first_index = first;
    m->n_samples = n;
    m->value_bytes = vb;
    m->axes = (uint8_t)axes;
    return AMBP_OK;
}

int ambp_decode(const uint8_t *d, size_t n, uint8_t version, const ambp_hmac_key *key, ambp_message *m) {
    const int sealed = version >= AMBP_AUTH_VERSION;
    if (n > AMBP_MAX_DATAGRAM) return AMBP_E_OVERSIZED;
    if (n < AMBP_OVERHEAD_BYTES) return AMBP_E_LENGTH;
    if (memcmp(d, "AMBP", 4) != 0) return AMBP_E_MAGIC;
    if (d[4] != version) return AMBP_E_VERSION;
    if (n < overhead(version)) return AMBP_E_LENGTH;
    if (ambp_crc32(d, n - 4) != get32(d + n - 4)) return AMBP_E_CRC;
    size_t pl = get16(d + 12);
    if (pl != n - overhead(version)) return AMBP_E_LENGTH;
    uint8_t kind = d[5];
    if (kind < AMBP_MEASUREMENT || kind > (sealed ? AMBP_WELCOME : AMBP_ACK)) return AMBP_E_KIND;
    const size_t hb = header_bytes(version);
    if (sealed) { /* the tag over header and payload, compared in constant time */
        uint8_t tag[AMBP_SHA256_BYTES];
        if (key == NULL) return AMBP_E_AUTH;
        ambp_hmac(key, d, hb + pl, tag);
        if (!ambp_equal_ct(tag, d + hb + pl, AMBP_TAG_BYTES)) return AMBP_E_AUTH;
        m->sender = d[6];
        memcpy(m->session, d + 16, AMBP_SESSION_BYTES);
    } else {
        m->sender = 0;
        memset(m->session, 0, AMBP_SESSION_BYTES);
    }
    const uint8_t *p = d + hb;
    m->kind = kind;
    m->sequence = get32(d + 8);
    switch (kind) {
    case AMBP_MEASUREMENT:
    case AMBP_EXCITATION: return decode_block(p, pl, version, m);
    case AMBP_HELLO:
        if (pl != AMBP_NONCE_BYTES) return AMBP_E_LENGTH;
        memcpy(m->bridge_nonce, p, AMBP_NONCE_BYTES);
        return AMBP_OK;
    case AMBP_WELCOME:
        if (pl != 2 * AMBP_NONCE_BYTES) return AMBP_E_LENGTH;
        memcpy(m->bridge_nonce, p, AMBP_NONCE_BYTES);
        memcpy(m->target_nonce, p + AMBP_NONCE_BYTES, AMBP_NONCE_BYTES);
        return AMBP_OK;
    case AMBP_HEARTBEAT:
        if (pl != (sealed ? 72u : 56u)) return AMBP_E_LENGTH;
        m->state = p[0]; m->safe_reason = p[1]; m->clock_running = p[2] != 0;
        m->axes = version == 1 ? 0 : p[3];
        m->sample_rate_hz = get32(p + 4);
        m->sample_index = get64(p + 8); m->sent_end = get64(p + 16); m->excitation_next = get64(p + 24);
        m->next_measurement_sequence = get32(p + 32); m->rx_datagrams = get32(p + 36);
        m->rx_rejected = get32(p + 40); m->late_excitation_samples = get32(p + 44); m->overruns = get32(p + 48);
        m->refused_auth = sealed ? get32(p + 56) : 0; m->refused_session = sealed ? get32(p + 60) : 0;
        m->refused_replay = sealed ? get32(p + 64) : 0; m->duplicates = sealed ? get32(p + 68) : 0;
        return AMBP_OK;
    case AMBP_COMMAND:
        if (pl != 32) return AMBP_E_LENGTH;
        m->command_id = get32(p); m->code = p[4];
        m->arg0 = get64(p + 8); m->arg1 = get64(p + 16); m->arg2 = get32(p + 24);
        return AMBP_OK;
    default: /* AMBP_ACK */
        if (pl != 16) return AMBP_E_LENGTH;
        m->command_id = get32(p); m->code = p[4]; m->result = p[5]; m->state = p[6];
        m->sample_index = get64(p + 8);
        return AMBP_OK;
    }
}

/* ---- the target ------------------------------------------------------------------------------- */
void ambp_default_config(ambp_config *cfg, uint32_t sample_rate_hz, uint8_t axes) {
    memset(cfg, 0, sizeof *cfg);
    cfg->version = AMBP_VERSION;
    cfg->axes = axes;
    cfg->value_bytes = 8;
    unsigned most = ambp_max_block(axes, 8, AMBP_VERSION);
    cfg->block = (uint16_t)(most < 10u ? most : 10u);
    cfg->sample_rate_hz = sample_rate_hz;
    cfg->heartbeat_ns = 50000000u;
    cfg->bridge_timeout_ns = 500000000u;
    cfg->safe_samples = (uint64_t)sample_rate_hz / 5u; /* 0.2 s */
}

int ambp_target_init(ambp_target *t, const ambp_config *cfg, ambp_exc_slot *storage, uint32_t capacity,
                     uint64_t now_ns) {
    unsigned most = ambp_max_block(cfg->axes, cfg->value_bytes, cfg->version);
    if (!axes_valid(cfg->axes, cfg->version) || most == 0 || cfg->block < 1 || cfg->block > most ||
        cfg->sample_rate_hz == 0 || cfg->heartbeat_ns == 0 || storage == NULL || capacity == 0)
        return -1;
    memset(t, 0, sizeof *t);
    t->cfg = *cfg;
    t->exc = storage;
    t->exc_capacity = capacity;
    for (uint32_t i = 0; i < capacity; i++) storage[i].index = AMBP_NO_INDEX;
    t->state = AMBP_IDLE;
    t->next_hb_ns = now_ns; /* the first poll announces the target */
    t->agreed = cfg->version < AMBP_AUTH_VERSION; /* before version 3 there is no session to agree */
    return 0;
}

/* ---- version 3: key, fingerprint, session ------------------------------------------------------- */
void ambp_key_fingerprint(const uint8_t *key, size_t n, char out[17]) {
    static const char hex[] = "0123456789abcdef";
    static const uint8_t prefix[] = "ambid link key"; /* and its NUL: 15 bytes */
    ambp_sha256_ctx c;
    uint8_t h[AMBP_SHA256_BYTES];
    ambp_sha256_init(&c);
    ambp_sha256_update(&c, prefix, sizeof prefix);
    ambp_sha256_update(&c, key, n);
    ambp_sha256_final(&c, h);
    for (unsigned i = 0; i < 8; i++) {
        out[2 * i] = hex[h[i] >> 4];
        out[2 * i + 1] = hex[h[i] & 15u];
    }
    out[16] = 0;
}

void ambp_session_id(const ambp_hmac_key *key, const uint8_t nb[AMBP_NONCE_BYTES],
                     const uint8_t nt[AMBP_NONCE_BYTES], uint8_t out[AMBP_SESSION_BYTES]) {
    static const uint8_t label[] = "AMBP3 session"; /* and its NUL: 14 bytes */
    uint8_t in[sizeof label + 2 * AMBP_NONCE_BYTES], mac[AMBP_SHA256_BYTES];
    memcpy(in, label, sizeof label);
    memcpy(in + sizeof label, nb, AMBP_NONCE_BYTES);
    memcpy(in + sizeof label + AMBP_NONCE_BYTES, nt, AMBP_NONCE_BYTES);
    ambp_hmac(key, in, sizeof in, mac);
    memcpy(out, mac, AMBP_SESSION_BYTES);
}

int ambp_target_set_key(ambp_target *t, const uint8_t *key, size_t n, const uint8_t seed[32]) {
    if (t->cfg.version < AMBP_AUTH_VERSION || n < AMBP_MIN_KEY_BYTES || n > AMBP_MAX_KEY_BYTES) return -1;
    ambp_hmac_key_init(&t->key, key, n);
    memcpy(t->nonce_seed, seed, sizeof t->nonce_seed);
    t->keyed = 1;
    return 0;
}

/* a target nonce never used before: HMAC(key, label | seed | count), the count never repeating in a run */
static void next_nonce(ambp_target *t, uint8_t out[AMBP_NONCE_BYTES]) {
    static const uint8_t label[] = "AMBP3 target nonce"; /* and its NUL: 19 bytes */
    uint8_t in[sizeof label + 32 + 8], mac[AMBP_SHA256_BYTES];
    memcpy(in, label, sizeof label);
    memcpy(in + sizeof label, t->nonce_seed, 32);
    put64(in + sizeof label + 32, t->nonces++);
    ambp_hmac(&t->key, in, sizeof in, mac);
    memcpy(out, mac, AMBP_NONCE_BYTES);
}

static void push_out(ambp_target *t, ambp_message *m) {
    m->sequence = t->seq[m->kind]++;
    m->sender = AMBP_SENDER_TARGET;
    if (m->kind != AMBP_WELCOME) memcpy(m->session, t->session, AMBP_SESSION_BYTES); /* a WELCOME names its own */
    if (t->out_count == AMBP_OUTBOX) { /* the caller did not drain: the oldest goes (counted) */
        t->out_head = (t->out_head + 1) % AMBP_OUTBOX;
        t->out_count--;
        t->tx_dropped++;
    }
    uint32_t slot = (t->out_head + t->out_count) % AMBP_OUTBOX;
    size_t n = ambp_encode(m, t->cfg.version, t->keyed ? &t->key : NULL, t->out[slot], AMBP_MAX_DATAGRAM);
    if (n == 0) { t->tx_dropped++; return; }
    t->out_len[slot] = (uint16_t)n;
    t->out_count++;
}

int ambp_target_tx(ambp_target *t, const uint8_t **data, size_t *len) {
    if (t->out_count == 0) return 0;
    *data = t->out[t->out_head];
    *len = t->out_len[t->out_head];
    t->out_head = (t->out_head + 1) % AMBP_OUTBOX;
    t->out_count--;
    return 1;
}

uint32_t ambp_target_rx_rejected(const ambp_target *t) {
    uint32_t s = 0;
    for (int i = 1; i < AMBP_N_REASONS; i++) s += t->rx_rejected_by_reason[i];
    return s;
}

static int have_excitation(const ambp_target *t, uint64_t i) {
    return t->exc[i % t->exc_capacity].index == i;
}

uint64_t ambp_target_excitation_next(const ambp_target *t) {
    uint64_t best = AMBP_NO_INDEX, window_end = t->k + t->exc_capacity;
    for (unsigned s = 0; s < AMBP_MAX_EXPERIMENTS; s++) {
        if (!t->range_used[s]) continue;
        uint64_t i = t->range_start[s] > t->k ? t->range_start[s] : t->k;
        uint64_t end = t->range_end[s] < window_end ? t->range_end[s] : window_end;
        for (; i < end && i < best; i++)
            if (!have_excitation(t, i)) { best = i; break; }
    }
    return best;
}

static void heartbeat(ambp_target *t, uint64_t now_ns) {
    ambp_message *m = &t->scratch;
    memset(m, 0, offsetof(ambp_message, data));
    m->kind = AMBP_HEARTBEAT;
    m->state = t->state;
    m->safe_reason = t->safe_reason;
    m->clock_running = t->clock_running;
    m->sample_rate_hz = t->cfg.sample_rate_hz;
    m->sample_index = t->k;
    m->sent_end = t->sent_end;
    m->excitation_next = ambp_target_excitation_next(t);
    m->next_measurement_sequence = t->seq[AMBP_MEASUREMENT];
    m->rx_datagrams = t->rx;
    m->rx_rejected = ambp_target_rx_rejected(t);
    m->late_excitation_samples = t->late_excitation;
    m->overruns = t->overruns;
    m->axes = t->cfg.axes;
    m->refused_auth = t->rx_rejected_by_reason[AMBP_E_AUTH];
    m->refused_session = t->rx_rejected_by_reason[AMBP_E_SESSION];
    m->refused_replay = t->rx_rejected_by_reason[AMBP_E_REPLAY];
    m->duplicates = t->rx_rejected_by_reason[AMBP_E_DUPLICATE];
    t->next_hb_ns = now_ns + t->cfg.heartbeat_ns;
    if (!t->agreed) return; /* version 3 before the session: nothing to seal it in */
    push_out(t, m);
}

static void send_block(ambp_target *t) {
    if (t->n_rows == 0) return;
    ambp_message *m = &t->scratch;
    m->kind = AMBP_MEASUREMENT;
    m->axes = t->cfg.axes;
    m->value_bytes = t->cfg.value_bytes;
    m->n_samples = t->n_rows;
    m->first_index = t->k - t->n_rows;
    memcpy(m->data, t->rows, sizeof(double) * 4u * t->cfg.axes * t->n_rows);
    memcpy(m->sample_flags, t->row_flags, t->n_rows);
    push_out(t, m);
    t->sent_end = t->k;
    t->n_rows = 0;
}

static void halt(ambp_target *t, uint8_t state, uint64_t now_ns) {
    send_block(t);
    t->state = state;
    t->clock_running = 0;
    heartbeat(t, now_ns);
}

static void enter_safe(ambp_target *t, uint8_t reason, uint64_t now_ns) {
    int was_running = t->state == AMBP_RUNNING;
    t->state = AMBP_SAFE;
    t->safe_reason = reason;
    t->safe_left = was_running ? t->cfg.safe_samples : 0;
    if (t->safe_left == 0) halt(t, AMBP_SAFE, now_ns);
    else heartbeat(t, now_ns); /* every state change is announced */
}

static void add_excitation(ambp_target *t, const ambp_message *m) {
    uint64_t first = m->first_index, n = m->n_samples;
    if (first + n <= t->k || first < t->k) t->excitation_late_datagrams++; /* (a part) already past: cut */
    for (uint64_t j = 0; j < n; j++) {
        uint64_t i = first + j;
        if (i < t->k) continue;
        if (i - t->k >= t->exc_capacity) { /* beyond the queue: asked for again via excitation_next */
            t->excitation_beyond_queue++;
            continue;
        }
        ambp_exc_slot *s = &t->exc[i % t->exc_capacity];
        s->index = i;
        memcpy(s->r, &m->data[m->axes * j], sizeof(double) * m->axes);
    }
}

static uint8_t execute(ambp_target *t, const ambp_message *c, uint64_t now_ns) {
    switch (c->code) {
    case AMBP_CMD_START:
        if (t->state == AMBP_RUNNING) return AMBP_ACK_OK;
        if (t->state != AMBP_IDLE) return AMBP_ACK_REFUSED;
        t->state = AMBP_RUNNING;
        t->clock_running = 1;
        return AMBP_ACK_OK;
    case AMBP_CMD_SAFE_STATE:
        if (t->state == AMBP_RUNNING || t->state == AMBP_IDLE) enter_safe(t, AMBP_SAFE_COMMANDED, now_ns);
        return AMBP_ACK_OK;
    case AMBP_CMD_STOP:
        if (t->state != AMBP_DONE) halt(t, AMBP_DONE, now_ns);
        t->stop_requested = 1;
        return AMBP_ACK_OK;
    case AMBP_CMD_EXPERIMENT: {
        int at = -1, free_slot = -1;
        for (unsigned s = 0; s < AMBP_MAX_EXPERIMENTS; s++) {
            if (t->range_used[s] && t->range_slot[s] == c->arg2) at = (int)s;
            if (!t->range_used[s] && free_slot < 0) free_slot = (int)s;
        }
        if (c->arg1 == 0) {
            if (at >= 0) t->range_used[at] = 0;
            return AMBP_ACK_OK;
        }
        if (c->arg1 >= AMBP_NO_INDEX - c->arg0) return AMBP_ACK_BAD_ARGUMENT;
        if (at < 0) at = free_slot;
        if (at < 0) return AMBP_ACK_REFUSED; /* AMBP_MAX_EXPERIMENTS announced and not cancelled */
        t->range_used[at] = 1;
        t->range_slot[at] = c->arg2;
        t->range_start[at] = c->arg0;
        t->range_end[at] = c->arg0 + c->arg1;
        return AMBP_ACK_OK;
    }
    default: return AMBP_ACK_BAD_ARGUMENT;
    }
}

static void command(ambp_target *t, uint64_t now_ns) {
    ambp_message *m = &t->scratch;
    uint32_t id = m->command_id;
    uint8_t code = m->code, result = 0;
    int known = 0;
    for (unsigned i = 0; i < AMBP_ACK_MEMORY; i++)
        if (t->ack_used[i] && t->ack_id[i] == id) { result = t->ack_result[i]; known = 1; break; }
    if (!known) {
        ambp_message c = *m; /* execute may send (and so reuse the scratch message) */
        result = execute(t, &c, now_ns);
        unsigned slot = t->ack_next++ % AMBP_ACK_MEMORY;
        t->ack_used[slot] = 1;
        t->ack_id[slot] = id;
        t->ack_result[slot] = result;
    }
    memset(m, 0, offsetof(ambp_message, data));
    m->kind = AMBP_ACK;
    m->command_id = id;
    m->code = code;
    m->result = result;
    m->state = t->state;
    m->sample_index = t->k;
    push_out(t, m);
    heartbeat(t, now_ns);
}

/* version 3: the WELCOME to the HELLO in the scratch message; the same answer to the same bridge nonce */
static void welcome(ambp_target *t) {
    ambp_message *m = &t->scratch;
    unsigned at = AMBP_PROPOSALS;
    for (unsigned i = 0; i < AMBP_PROPOSALS; i++)
        if (t->prop_used[i] && memcmp(t->prop_nb[i], m->bridge_nonce, AMBP_NONCE_BYTES) == 0) at = i;
    if (at == AMBP_PROPOSALS) { /* a new proposal replaces the oldest */
        at = t->prop_next++ % AMBP_PROPOSALS;
        t->prop_used[at] = 1;
        memcpy(t->prop_nb[at], m->bridge_nonce, AMBP_NONCE_BYTES);
        next_nonce(t, t->prop_nt[at]);
        ambp_session_id(&t->key, t->prop_nb[at], t->prop_nt[at], t->prop_session[at]);
    }
    memset(m, 0, offsetof(ambp_message, data));
    m->kind = AMBP_WELCOME;
    memcpy(m->bridge_nonce, t->prop_nb[at], AMBP_NONCE_BYTES);
    memcpy(m->target_nonce, t->prop_nt[at], AMBP_NONCE_BYTES);
    memcpy(m->session, t->prop_session[at], AMBP_SESSION_BYTES);
    push_out(t, m);
}

/* version 3: what depends on the link's state (the sender, the session, the replay window), in the order
 * of docs/bridge_protocol.md; *committed set when this datagram confirmed a proposed session */
static int link_check(ambp_target *t, int *committed) {
    static const uint8_t no_session[AMBP_SESSION_BYTES] = {0};
    ambp_message *m = &t->scratch;
    const uint8_t kind = m->kind;
    if (m->sender != AMBP_SENDER_BRIDGE ||
        !(kind == AMBP_EXCITATION || kind == AMBP_HEARTBEAT || kind == AMBP_COMMAND || kind == AMBP_HELLO))
        return AMBP_E_DIRECTION;
    if (kind == AMBP_HELLO) {
        if (memcmp(m->session, no_session, AMBP_SESSION_BYTES) != 0) return AMBP_E_SESSION;
        if (t->agreed) /* a late repeat of the agreed session's HELLO needs no answer; any other is refused */
            return memcmp(m->bridge_nonce, t->agreed_bridge_nonce, AMBP_NONCE_BYTES) == 0 ? AMBP_OK : AMBP_E_SESSION;
        welcome(t);
        return AMBP_OK;
    }
    int prop = -1;
    if (t->agreed) {
        if (memcmp(m->session, t->session, AMBP_SESSION_BYTES) != 0) return AMBP_E_SESSION;
    } else {
        for (unsigned i = 0; i < AMBP_PROPOSALS; i++)
            if (t->prop_used[i] && memcmp(m->session, t->prop_session[i], AMBP_SESSION_BYTES) == 0) prop = (int)i;
        if (prop < 0) return AMBP_E_SESSION;
    }
    uint32_t *top = &t->win_top[kind];
    uint64_t *bits = &t->win_bits[kind];
    if (*bits == 0) { /* the kind's first datagram in the session */
        *top = m->sequence;
        *bits = 1;
    } else {
        uint32_t u = m->sequence - *top; /* the wrapping difference, in [-2^31, 2^31) */
        int64_t diff = u < 0x80000000u ? (int64_t)u : (int64_t)u - 4294967296LL;
        if (diff > 0) {
            *bits = diff < (int64_t)AMBP_WINDOW ? (*bits << diff) | 1u : 1u;
            *top = m->sequence;
        } else {
            uint64_t back = (uint64_t)(-diff);
            if (back >= AMBP_WINDOW) return AMBP_E_REPLAY;
            if ((*bits >> back) & 1u) return AMBP_E_DUPLICATE;
            *bits |= (uint64_t)1 << back;
        }
    }
    if (prop >= 0) { /* the bridge confirmed this proposal: the session, for the rest of the run */
        t->agreed = 1;
        memcpy(t->session, t->prop_session[prop], AMBP_SESSION_BYTES);
        memcpy(t->agreed_bridge_nonce, t->prop_nb[prop], AMBP_NONCE_BYTES);
        memset(t->prop_used, 0, sizeof t->prop_used);
        *committed = 1;
    }
    return AMBP_OK;
}

int ambp_target_receive(ambp_target *t, const uint8_t *d, size_t n, int from_bridge, uint64_t now_ns) {
    if (!from_bridge) {
        t->rx_rejected_by_reason[AMBP_E_FOREIGN]++;
        return AMBP_E_FOREIGN;
    }
    const int sealed = t->cfg.version >= AMBP_AUTH_VERSION;
    int why = ambp_decode(d, n, t->cfg.version, t->keyed ? &t->key : NULL, &t->scratch);
    if (why == AMBP_OK && t->scratch.kind == AMBP_EXCITATION && t->scratch.axes != t->cfg.axes)
        why = AMBP_E_CONTENT; /* another rig's channels */
    int committed = 0;
    const uint8_t kind = t->scratch.kind; /* link_check may answer a HELLO in the scratch message */
    if (why == AMBP_OK && sealed) why = link_check(t, &committed);
    if (why != AMBP_OK) {
        t->rx_rejected_by_reason[why]++;
        return why;
    }
    if (kind == AMBP_HELLO) { /* answered (link_check); not a sign of the bridge in the session */
        t->rx++;
        return AMBP_OK;
    }
    t->rx++;
    t->heard = 1;
    t->last_rx_ns = now_ns;
    switch (t->scratch.kind) {
    case AMBP_EXCITATION: add_excitation(t, &t->scratch); break;
    case AMBP_COMMAND: command(t, now_ns); break;
    case AMBP_HEARTBEAT: break;
    default: /* MEASUREMENT or ACK never go to a target */
        t->rx_unexpected_kind++;
        t->rx_rejected_by_reason[AMBP_E_KIND]++;
        break;
    }
    if (committed) heartbeat(t, now_ns); /* the session is agreed: the bridge hears the target at once */
    return AMBP_OK;
}

void ambp_target_poll(ambp_target *t, uint64_t now_ns) {
    if (t->state == AMBP_RUNNING && t->heard && now_ns - t->last_rx_ns > t->cfg.bridge_timeout_ns)
        enter_safe(t, AMBP_SAFE_BRIDGE_SILENT, now_ns);
    if (now_ns >= t->next_hb_ns) heartbeat(t, now_ns);
}

void ambp_target_count_overrun(ambp_target *t) { t->overruns++; }

static int announced(const ambp_target *t, uint64_t k) {
    for (unsigned s = 0; s < AMBP_MAX_EXPERIMENTS; s++)
        if (t->range_used[s] && t->range_start[s] <= k && k < t->range_end[s]) return 1;
    return 0;
}

int ambp_target_sample_begin(ambp_target *t, double *r, uint8_t *flags) {
    const unsigned na = t->cfg.axes;
    *flags = 0;
    for (unsigned i = 0; i < na; i++) r[i] = 0.0;
    if (!t->clock_running) return AMBP_SAMPLE_STOPPED;
    if (t->state == AMBP_SAFE) {
        *flags = AMBP_FLAG_SAFE_STATE;
        return AMBP_SAMPLE_SAFE;
    }
    const ambp_exc_slot *s = &t->exc[t->k % t->exc_capacity];
    if (s->index == t->k) {
        memcpy(r, s->r, sizeof(double) * na);
    } else if (announced(t, t->k)) {
        if (t->cfg.hold_for_excitation) return AMBP_SAMPLE_HOLD;
        *flags = AMBP_FLAG_EXCITATION_LATE; /* a real-time loop cannot wait: r = 0, counted */
        t->late_excitation++;
    }
    return AMBP_SAMPLE_CONTROL;
}

void ambp_target_sample_end(ambp_target *t, const double *y, const double *u, const double *ic,
                            const double *r, uint8_t flags, uint64_t now_ns) {
    const unsigned na = t->cfg.axes;
    double *row = &t->rows[4u * na * t->n_rows];
    memcpy(row, y, na * sizeof(double));
    memcpy(row + na, u, na * sizeof(double));
    memcpy(row + 2 * na, ic, na * sizeof(double));
    memcpy(row + 3 * na, r, na * sizeof(double));
    t->row_flags[t->n_rows++] = flags;
    t->exc[t->k % t->exc_capacity].index = AMBP_NO_INDEX; /* applied: the slot is free for k + capacity */
    t->k++;
    if (t->state == AMBP_SAFE && t->safe_left > 0) t->safe_left--;
    if (t->n_rows == t->cfg.block) send_block(t);
    if (t->cfg.max_samples && t->k >= t->cfg.max_samples) halt(t, AMBP_DONE, now_ns);
    else if (t->state == AMBP_SAFE && t->safe_left == 0) halt(t, AMBP_SAFE, now_ns);
}
