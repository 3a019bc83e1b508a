/* ambp_hmac: SHA-256 and HMAC-SHA-256. See ambp_hmac.h. */
#include "ambp_hmac.h"

#include <string.h>

static const uint32_t K256[64] = {
    0x428a2f98u, 0x71374491u, 0xb5c0fbcfu, 0xe9b5dba5u, 0x3956c25bu, 0x59f111f1u, 0x923f82a4u, 0xab1c5ed5u,
    0xd807aa98u, 0x12835b01u, 0x243185beu, 0x550c7dc3u, 0x72be5d74u, 0x80deb1feu, 0x9bdc06a7u, 0xc19bf174u,
    0xe49b69c1u, 0xefbe4786u, 0x0fc19dc6u, 0x240ca1ccu, 0x2de92c6fu, 0x4a7484aau, 0x5cb0a9dcu, 0x76f988dau,
    0x983e5152u, 0xa831c66du, 0xb00327c8u, 0xbf597fc7u, 0xc6e00bf3u, 0xd5a79147u, 0x06ca6351u, 0x14292967u,
    0x27b70a85u, 0x2e1b2138u, 0x4d2c6dfcu, 0x53380d13u, 0x650a7354u, 0x766a0abbu, 0x81c2c92eu, 0x92722c85u,
    0xa2bfe8a1u, 0xa81a664bu, 0xc24b8b70u, 0xc76c51a3u, 0xd192e819u, 0xd6990624u, 0xf40e3585u, 0x106aa070u,
    0x19a4c116u, 0x1e376c08u, 0x2748774cu, 0x34b0bcb5u, 0x391c0cb3u, 0x4ed8aa4au, 0x5b9cca4fu, 0x682e6ff3u,
    0x748f82eeu, 0x78a5636fu, 0x84c87814u, 0x8cc70208u, 0x90befffau, 0xa4506cebu, 0xbef9a3f7u, 0xc67178f2u};

static uint32_t rotr(uint32_t x, unsigned n) { return (x >> n) | (x << (32u - n)); }

static void compress(uint32_t h[8], const uint8_t *p) {
    uint32_t w[64];
    for (unsigned i = 0; i < 16; i++)
        w[i] = ((uint32_t)p[4 * i] << 24) | ((uint32_t)p[4 * i + 1] << 16) | ((uint32_t)p[4 * i + 2] << 8) |
               (uint32_t)p[4 * i + 3];
    for (unsigned i = 16; i < 64; i++) {
        uint32_t s0 = rotr(w[i - 15], 7) ^ rotr(w[i - 15], 18) ^ (w[i - 15] >> 3);
        uint32_t s1 = rotr(w[i - 2], 17) ^ rotr(w[i - 2], 19) ^ (w[i - 2] >> 10);
        w[i] = w[i - 16] + s0 + w[i - 7] + s1;
    }
    uint32_t a = h[0], b = h[1], c = h[2], d = h[3], e = h[4], f = h[5], g = h[6], hh = h[7];
    for (unsigned i = 0; i < 64; i++) {
        uint32_t t1 = hh + (rotr(e, 6) ^ rotr(e, 11) ^ rotr(e, 25)) + ((e & f) ^ (~e & g)) + K256[i] + w[i];
        uint32_t t2 = (rotr(a, 2) ^ rotr(a, 13) ^ rotr(a, 22)) + ((a & b) ^ (a & c) ^ (b & c));
        hh = g; g = f; f = e; e = d + t1; d = c; c = b; b = a; a = t1 + t2;
    }
    h[0] += a; h[1] += b; h[2] += c; h[3] += d; h[4] += e; h[5] += f; h[6] += g; h[7] += hh;
}

void ambp_sha256_init(ambp_sha256_ctx *c) {
    static const uint32_t h0[8] = {0x6a09e667u, 0xbb67ae85u, 0x3c6ef372u, 0xa54ff53au,
                                   0x510e527fu, 0x9b05688cu, 0x1f83d9abu, 0x5be0cd19u};
    memcpy(c->h, h0, sizeof h0);
    c->bytes = 0;
    c->fill = 0;
}

void ambp_sha256_update(ambp_sha256_ctx *c, const uint8_t *d, size_t n) {
    c->bytes += n;
    if (c->fill) {
        size_t take = AMBP_SHA256_BLOCK - c->fill;
        if (take > n) take = n;
        memcpy(c->buf + c->fill, d, take);
        c->fill += (uint32_t)take;
        d += take;
        n -= take;
        if (c->fill < AMBP_SHA256_BLOCK) return;
        compress(c->h, c->buf);
        c->fill = 0;
    }
    for (; n >= AMBP_SHA256_BLOCK; d += AMBP_SHA256_BLOCK, n -= AMBP_SHA256_BLOCK) compress(c->h, d);
    if (n) {
        memcpy(c->buf, d, n);
        c->fill = (uint32_t)n;
    }
}

void ambp_sha256_final(ambp_sha256_ctx *c, uint8_t out[AMBP_SHA256_BYTES]) {
    uint64_t bits = c->bytes * 8u;
    uint8_t pad[AMBP_SHA256_BLOCK + 8];
    size_t npad = (c->fill < 56u ? 56u : 120u) - c->fill; /* 0x80, zeros, to 56 mod 64 */
    memset(pad, 0, sizeof pad);
    pad[0] = 0x80;
    for (unsigned i = 0; i < 8; i++) pad[npad + i] = (uint8_t)(bits >> (56 - 8 * i));
    ambp_sha256_update(c, pad, npad + 8);
    for (unsigned i = 0; i < 8; i++) {
        out[4 * i] = (uint8_t)(c->h[i] >> 24);
        out[4 * i + 1] = (uint8_t)(c->h[i] >> 16);
        out[4 * i + 2] = (uint8_t)(c->h[i] >> 8);
        out[4 * i + 3] = (uint8_t)c->h[i];
    }
}

void ambp_sha256(const uint8_t *d, size_t n, uint8_t out[AMBP_SHA256_BYTES]) {
    ambp_sha256_ctx c;
    ambp_sha256_init(&c);
    ambp_sha256_update(&c, d, n);
    ambp_sha256_final(&c, out);
}

void ambp_hmac_key_init(ambp_hmac_key *k, const uint8_t *key, size_t n) {
    uint8_t block[AMBP_SHA256_BLOCK], pad[AMBP_SHA256_BLOCK];
    memset(block, 0, sizeof block);
    if (n > AMBP_SHA256_BLOCK) ambp_sha256(key, n, block); /* a long key is hashed first (RFC 2104) */
    else if (n) memcpy(block, key, n);
    for (unsigned i = 0; i < AMBP_SHA256_BLOCK; i++) pad[i] = (uint8_t)(block[i] ^ 0x36u);
    ambp_sha256_init(&k->inner);
    ambp_sha256_update(&k->inner, pad, AMBP_SHA256_BLOCK);
    for (unsigned i = 0; i < AMBP_SHA256_BLOCK; i++) pad[i] = (uint8_t)(block[i] ^ 0x5cu);
    ambp_sha256_init(&k->outer);
    ambp_sha256_update(&k->outer, pad, AMBP_SHA256_BLOCK);
    ambp_wipe(block, sizeof block);
    ambp_wipe(pad, sizeof pad);
}

void ambp_hmac2(const ambp_hmac_key *k, const uint8_t *a, size_t na, const uint8_t *b, size_t nb,
                uint8_t out[AMBP_SHA256_BYTES]) {
    ambp_sha256_ctx c = k->inner;
    uint8_t inner[AMBP_SHA256_BYTES];
    ambp_sha256_update(&c, a, na);
    if (nb) ambp_sha256_update(&c, b, nb);
    ambp_sha256_final(&c, inner);
    c = k->outer;
    ambp_sha256_update(&c, inner, sizeof inner);
    ambp_sha256_final(&c, out);
}

void ambp_hmac(const ambp_hmac_key *k, const uint8_t *d, size_t n, uint8_t out[AMBP_SHA256_BYTES]) {
    ambp_hmac2(k, d, n, NULL, 0, out);
}

void ambp_hmac_sha256(const uint8_t *key, size_t key_len, const uint8_t *d, size_t n,
                      uint8_t out[AMBP_SHA256_BYTES]) {
    ambp_hmac_key k;
    ambp_hmac_key_init(&k, key, key_len);
    ambp_hmac(&k, d, n, out);
    ambp_wipe(&k, sizeof k);
}

int ambp_equal_ct(const uint8_t *a, const uint8_t *b, size_t n) {
    volatile uint8_t diff = 0; /* every byte is compared, whatever the first difference */
    for (size_t i = 0; i < n; i++) diff |= (uint8_t)(a[i] ^ b[i]);
    return diff == 0;
}

void ambp_wipe(void *p, size_t n) {
    volatile uint8_t *v = (volatile uint8_t *)p;
    while (n--) *v++ = 0;
}
