/* ambp_hmac: SHA-256 (FIPS 180-4) and HMAC-SHA-256 (RFC 2104) in portable C99, for the authenticated link of
 * protocol version 3 (docs/bridge_protocol.md). No heap, no OS calls, no globals that change; byte order
 * written explicitly. Checked against the FIPS 180-4 examples and the RFC 4231 vectors
 * (tests/core/test_target_c_hmac.py).
 */
#ifndef AMBP_HMAC_H
#define AMBP_HMAC_H

#include <stddef.h>
#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define AMBP_SHA256_BYTES 32u
#define AMBP_SHA256_BLOCK 64u

typedef struct {
    uint32_t h[8];
    uint64_t bytes;               /* message bytes hashed so far */
    uint8_t buf[AMBP_SHA256_BLOCK];
    uint32_t fill;                /* bytes waiting in buf */
} ambp_sha256_ctx;

void ambp_sha256_init(ambp_sha256_ctx *c);
void ambp_sha256_update(ambp_sha256_ctx *c, const uint8_t *d, size_t n);
void ambp_sha256_final(ambp_sha256_ctx *c, uint8_t out[AMBP_SHA256_BYTES]);
void ambp_sha256(const uint8_t *d, size_t n, uint8_t out[AMBP_SHA256_BYTES]);

/* A key ready for HMAC: the hash states after its inner and outer pads, computed once, so a tag costs the
 * message's blocks plus two (RFC 2104, section 4). Keys longer than 64 bytes are hashed first. */
typedef struct {
    ambp_sha256_ctx inner, outer;
} ambp_hmac_key;

void ambp_hmac_key_init(ambp_hmac_key *k, const uint8_t *key, size_t n);
/* HMAC-SHA-256 of the concatenation a[na] | b[nb] (b may be NULL with nb 0) under k: 32 bytes into out */
void ambp_hmac2(const ambp_hmac_key *k, const uint8_t *a, size_t na, const uint8_t *b, size_t nb,
                uint8_t out[AMBP_SHA256_BYTES]);
void ambp_hmac(const ambp_hmac_key *k, const uint8_t *d, size_t n, uint8_t out[AMBP_SHA256_BYTES]);
/* one-shot: HMAC-SHA-256(key, d) */
void ambp_hmac_sha256(const uint8_t *key, size_t key_len, const uint8_t *d, size_t n,
                      uint8_t out[AMBP_SHA256_BYTES]);

/* 1 when a[n] equals b[n]; the time taken does not depend on where they differ */
int ambp_equal_ct(const uint8_t *a, const uint8_t *b, size_t n);

/* overwrite n bytes at p with zeros in a way the compiler does not drop (a key no longer needed) */
void ambp_wipe(void *p, size_t n);

#ifdef __cplusplus
}
#endif
#endif
