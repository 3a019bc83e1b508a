/* ambp_bench: what the protocol costs the C target per datagram, unauthenticated (version 2) and sealed
 * (version 3), on this machine: the target's own MEASUREMENT datagram encoded (and, version 3, tagged), and
 * the bridge's EXCITATION datagram decoded (and its tag checked), each timed over many repetitions in the
 * thread's CPU time (CLOCK_THREAD_CPUTIME_ID: a shared machine's other work is not counted). `ambid bench` runs it (section link) and prints its figures.
 *
 *   ambp_bench [--axes N] [--repeats N]
 *
 * Prints AMBP_BENCH {json}: ns per datagram for each version and operation, and the datagrams' sizes.
 */
#define _POSIX_C_SOURCE 200809L

#include "ambp.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

/* CPU time of this thread: what the work costs, whatever else the machine runs meanwhile */
static uint64_t now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ull + (uint64_t)ts.tv_nsec;
}

static ambp_message meas, exc, scratch;
static uint8_t buf[AMBP_MAX_DATAGRAM], exc_datagram[AMBP_MAX_DATAGRAM];
static volatile size_t sink; /* keeps the compiler from dropping the work */

/* ns per call of encode (what = 0) or decode (1) of the prepared datagrams, the best of 5 rounds */
static double time_op(int what, uint8_t version, const ambp_hmac_key *key, size_t exc_len, long repeats) {
    double best = 1e300;
    for (int round = 0; round < 5; round++) {
        uint64_t t0 = now_ns();
        for (long i = 0; i < repeats; i++) {
            if (what == 0) {
                meas.sequence = (uint32_t)i;
                sink += ambp_encode(&meas, version, key, buf, sizeof buf);
            } else {
                sink += (size_t)ambp_decode(exc_datagram, exc_len, version, key, &scratch);
            }
        }
        double ns = (double)(now_ns() - t0) / (double)repeats;
        if (ns < best) best = ns;
    }
    return best;
}

int main(int argc, char **argv) {
    unsigned axes = 4;
    long repeats = 20000;
    for (int i = 1; i + 1 < argc; i += 2) {
        if (!strcmp(argv[i], "--axes")) axes = (unsigned)atoi(argv[i + 1]);
        else if (!strcmp(argv[i], "--repeats")) repeats = atol(argv[i + 1]);
        else {
            fprintf(stderr, "ambp_bench: unknown option '%s'; usage: ambp_bench [--axes N] [--repeats N]\n", argv[i]);
            return 2;
        }
    }
    if (axes < 1 || axes > AMBP_MAX_AXES || repeats < 1) {
        fprintf(stderr, "ambp_bench: --axes must be 1 to %u and --repeats at least 1\n", AMBP_MAX_AXES);
        return 2;
    }
    uint8_t secret[32];
    for (unsigned i = 0; i < sizeof secret; i++) secret[i] = (uint8_t)(17u * i + 3u);
    ambp_hmac_key key;
    ambp_hmac_key_init(&key, secret, sizeof secret);

    /* the target's default MEASUREMENT (10 samples, float64) and the bridge's EXCITATION (40 samples) */
    meas.kind = AMBP_MEASUREMENT;
    meas.axes = (uint8_t)axes;
    meas.value_bytes = 8;
    unsigned most = ambp_max_block(axes, 8, AMBP_AUTH_VERSION); /* what both versions carry */
    meas.n_samples = (uint16_t)(most < 10u ? most : 10u);
    meas.sender = AMBP_SENDER_TARGET;
    for (unsigned i = 0; i < meas.n_samples * 4u * axes; i++) meas.data[i] = 1e-6 * (double)i;
    exc.kind = AMBP_EXCITATION;
    exc.axes = (uint8_t)axes;
    exc.value_bytes = 8;
    unsigned exc_most = (AMBP_MAX_DATAGRAM - AMBP_OVERHEAD_V3_BYTES - AMBP_BLOCK_HEADER_BYTES) / (8u * axes);
    exc.n_samples = (uint16_t)(exc_most < 40u ? exc_most : 40u);
    exc.sender = AMBP_SENDER_BRIDGE;
    for (unsigned i = 0; i < exc.n_samples * axes; i++) exc.data[i] = 0.01 * (double)(i % 7);

    printf("AMBP_BENCH {\"axes\": %u, \"repeats\": %ld, \"measurement_samples\": %u, \"excitation_samples\": %u",
           axes, repeats, meas.n_samples, exc.n_samples);
    for (uint8_t version = 2; version <= 3; version++) {
        const ambp_hmac_key *k = version >= AMBP_AUTH_VERSION ? &key : NULL;
        size_t meas_len = ambp_encode(&meas, version, k, buf, sizeof buf);
        size_t exc_len = ambp_encode(&exc, version, k, exc_datagram, sizeof exc_datagram);
        if (!meas_len || !exc_len || ambp_decode(exc_datagram, exc_len, version, k, &scratch) != AMBP_OK) {
            fprintf(stderr, "ambp_bench: version %u datagrams did not encode and decode\n", version);
            return 1;
        }
        double enc = time_op(0, version, k, exc_len, repeats), dec = time_op(1, version, k, exc_len, repeats);
        printf(", \"v%u\": {\"measurement_bytes\": %zu, \"excitation_bytes\": %zu, \"encode_measurement_ns\": %.1f, "
               "\"decode_excitation_ns\": %.1f}", version, meas_len, exc_len, enc, dec);
    }
    printf("}\n");
    return sink == 0; /* never: the encodes return lengths */
}
