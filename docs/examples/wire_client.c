/*
 * A Tether peer in C, written from docs/wire.md: libzmq and a few hand-written msgpack bytes.
 *
 *     cc -std=c99 -O1 -Wall -o wire_client wire_client.c -lzmq
 *     ./wire_client PUB_TOPIC SUB_ENDPOINT SUB_TOPIC [SUB_TOPIC ...] COUNT
 *
 * Publisher: binds a PUB socket at ipc://<runtime dir>/s/wirec.<pid>, registers PUB_TOPIC
 * (type std.Float64) in the registry (docs/wire.md 6) and publishes std.Float64 messages
 * numbered 1, 2, 3, ... at 50 Hz. Subscriber: connects to SUB_ENDPOINT (reading the
 * registry's JSON is left to a JSON library; this example is told the endpoint), subscribes
 * to each SUB_TOPIC and prints each message as one JSON line: type, seq, stamp_ns, and data
 * (a number, or an array's dtype, shape and buffer in hex). It exits 0 once COUNT messages
 * of every SUB_TOPIC have arrived, 1 after 30 s, removing its registry entry either way.
 * A malformed message is one line on stderr, counted, and skipped.
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>
#include <zmq.h>

#define MAX_TOPICS 8
#define MAX_FRAMES 16

/* -- msgpack: the encoder bytes a std.Float64 needs (docs/wire.md 4) ---------------------- */
static uint8_t *put_be(uint8_t *p, uint64_t v, int n) {
    for (int i = n - 1; i >= 0; i--) *p++ = (uint8_t)(v >> (8 * i));
    return p;
}

static uint8_t *put_str(uint8_t *p, const char *s) {   /* fixstr: fewer than 32 bytes */
    size_t n = strlen(s);
    *p++ = (uint8_t)(0xa0 | n);
    memcpy(p, s, n);
    return p + n;
}

static size_t float64_body(uint8_t *buf, double value, uint64_t stamp_ns, uint64_t seq) {
    uint64_t bits;
    uint8_t *p = buf;
    memcpy(&bits, &value, sizeof bits);
    *p++ = 0x85;                                        /* a map of 5 entries */
    p = put_str(p, "type");     p = put_str(p, "std.Float64");
    p = put_str(p, "data");     *p++ = 0xcb; p = put_be(p, bits, 8);      /* float 64 */
    p = put_str(p, "stamp_ns"); *p++ = 0xcf; p = put_be(p, stamp_ns, 8);  /* uint 64 */
    p = put_str(p, "frame_id"); p = put_str(p, "");
    p = put_str(p, "seq");      *p++ = 0xcf; p = put_be(p, seq, 8);
    return (size_t)(p - buf);
}

/* -- msgpack: a bounds-checked reader ------------------------------------------------------ */
typedef struct { const uint8_t *p, *end; int bad; } rd_t;

static uint64_t get_be(rd_t *r, int n) {
    uint64_t v = 0;
    if (r->end - r->p < n) { r->bad = 1; return 0; }
    for (int i = 0; i < n; i++) v = (v << 8) | *r->p++;
    return v;
}

static int get_byte(rd_t *r) { return (int)get_be(r, 1); }

/* A string's bytes (not NUL-terminated); 0 if the next value is not a string. */
static int get_str(rd_t *r, const char **s, uint32_t *n) {
    int t = get_byte(r);
    if (t >= 0xa0 && t <= 0xbf) *n = (uint32_t)(t & 0x1f);
    else if (t == 0xd9) *n = (uint32_t)get_be(r, 1);
    else if (t == 0xda) *n = (uint32_t)get_be(r, 2);
    else if (t == 0xdb) *n = (uint32_t)get_be(r, 4);
    else { r->bad = 1; return 0; }
    if (r->bad || (uint64_t)(r->end - r->p) < *n) { r->bad = 1; return 0; }
    *s = (const char *)r->p;
    r->p += *n;
    return 1;
}

/* A container header: returns its entry count and sets *is_map; -1 if not a container. */
static int64_t get_container(rd_t *r, int *is_map) {
    int t = get_byte(r);
    *is_map = (t >= 0x80 && t <= 0x8f) || t == 0xde || t == 0xdf;
    if (t >= 0x80 && t <= 0x9f) return t & 0x0f;
    if (t == 0xdc || t == 0xde) return (int64_t)get_be(r, 2);
    if (t == 0xdd || t == 0xdf) return (int64_t)get_be(r, 4);
    r->bad = 1;
    return -1;
}

/* Any number as a double (ints, floats); *is_int says whether it was an integer. */
static double get_number(rd_t *r, int *is_int, int64_t *as_int) {
    int t = get_byte(r);
    *is_int = 1;
    if (t <= 0x7f) { *as_int = t; return t; }
    if (t >= 0xe0) { *as_int = (int8_t)t; return (double)*as_int; }
    if (t >= 0xcc && t <= 0xcf) { uint64_t u = get_be(r, 1 << (t - 0xcc)); *as_int = (int64_t)u; return (double)u; }
    if (t >= 0xd0 && t <= 0xd3) {
        int n = 1 << (t - 0xd0);
        uint64_t u = get_be(r, n);
        int64_t v = n == 8 ? (int64_t)u : (int64_t)(u ^ (1ULL << (8 * n - 1))) - (int64_t)(1ULL << (8 * n - 1));
        *as_int = v;
        return (double)v;
    }
    *is_int = 0;
    if (t == 0xca) { uint32_t b = (uint32_t)get_be(r, 4); float f; memcpy(&f, &b, 4); return f; }
    if (t == 0xcb) { uint64_t b = get_be(r, 8); double d; memcpy(&d, &b, 8); return d; }
    r->bad = 1;
    return 0;
}

static void skip(rd_t *r, int depth) {
    if (r->bad || r->p >= r->end || depth > 32) { r->bad = 1; return; }
    int t = *r->p;
    uint64_t n = 0;
    if (t <= 0x7f || t >= 0xe0 || t == 0xc0 || t == 0xc2 || t == 0xc3) { r->p++; return; }
    if ((t >= 0xa0 && t <= 0xbf) || (t >= 0xd9 && t <= 0xdb)) { const char *s; uint32_t k; get_str(r, &s, &k); return; }
    if ((t >= 0x80 && t <= 0x9f) || (t >= 0xdc && t <= 0xdf)) {
        int is_map;
        int64_t count = get_container(r, &is_map);
        for (int64_t i = 0; i < count * (is_map ? 2 : 1) && !r->bad; i++) skip(r, depth + 1);
        return;
    }
    r->p++;
    switch (t) {
    case 0xc4: n = get_be(r, 1); break;                       /* bin 8/16/32 */
    case 0xc5: n = get_be(r, 2); break;
    case 0xc6: n = get_be(r, 4); break;
    case 0xc7: n = get_be(r, 1) + 1; break;                   /* ext 8/16/32: length, then the type byte */
    case 0xc8: n = get_be(r, 2) + 1; break;
    case 0xc9: n = get_be(r, 4) + 1; break;
    case 0xca: n = 4; break;
    case 0xcb: n = 8; break;
    case 0xcc: case 0xd0: n = 1; break;
    case 0xcd: case 0xd1: n = 2; break;
    case 0xce: case 0xd2: n = 4; break;
    case 0xcf: case 0xd3: n = 8; break;
    case 0xd4: n = 2; break;                                  /* fixext 1/2/4/8/16, plus the type byte */
    case 0xd5: n = 3; break;
    case 0xd6: n = 5; break;
    case 0xd7: n = 9; break;
    case 0xd8: n = 17; break;
    default: r->bad = 1; return;
    }
    if (r->bad || (uint64_t)(r->end - r->p) < n) { r->bad = 1; return; }
    r->p += n;
}

static int key_is(const char *s, uint32_t n, const char *want) { return strlen(want) == n && !memcmp(s, want, n); }

/* -- one message to one JSON line (docs/wire.md 3, 4, 5) ----------------------------------- */
typedef struct { char *p, *end; } out_t;

static void emit(out_t *o, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(o->p, (size_t)(o->end - o->p), fmt, ap);
    va_end(ap);
    if (n > 0) o->p += (n < o->end - o->p) ? n : (o->end - o->p - 1);
}

static void emit_str(out_t *o, const char *s, uint32_t n) {
    emit(o, "\"");
    for (uint32_t i = 0; i < n; i++) {
        unsigned char c = (unsigned char)s[i];
        if (c == '"' || c == '\\') emit(o, "\\%c", c);
        else if (c < 0x20) emit(o, "\\u%04x", c);
        else emit(o, "%c", c);
    }
    emit(o, "\"");
}

/* The array map {dtype, shape, frame} (buffer in frames[2 + frame]) or {dtype, shape, data}. */
static void emit_array(out_t *o, rd_t *r, int64_t count, zmq_msg_t *frames, int nframes) {
    const uint8_t *buf = NULL;
    size_t nbuf = 0;
    emit(o, "{");
    for (int64_t i = 0; i < count && !r->bad; i++) {
        const char *k; uint32_t kn;
        if (!get_str(r, &k, &kn)) return;
        if (key_is(k, kn, "dtype")) {
            const char *s; uint32_t n;
            if (!get_str(r, &s, &n)) return;
            emit(o, "\"dtype\": "); emit_str(o, s, n); emit(o, ", ");
        } else if (key_is(k, kn, "shape")) {
            int is_map, is_int; int64_t v;
            int64_t dims = get_container(r, &is_map);
            if (is_map || dims < 0) { r->bad = 1; return; }
            emit(o, "\"shape\": [");
            for (int64_t d = 0; d < dims && !r->bad; d++) {
                get_number(r, &is_int, &v);
                if (!is_int || v < 0) { r->bad = 1; return; }
                emit(o, d ? ", %lld" : "%lld", (long long)v);
            }
            emit(o, "], ");
        } else if (key_is(k, kn, "frame")) {
            int is_int; int64_t v;
            get_number(r, &is_int, &v);
            if (!is_int || v < 0 || v + 2 >= nframes) { r->bad = 1; return; }   /* 0 = the frame after the body */
            buf = zmq_msg_data(&frames[2 + v]);
            nbuf = zmq_msg_size(&frames[2 + v]);
        } else if (key_is(k, kn, "data")) {
            int t = r->p < r->end ? *r->p++ : -1;
            uint64_t n = t == 0xc4 ? get_be(r, 1) : t == 0xc5 ? get_be(r, 2) : t == 0xc6 ? get_be(r, 4) : (r->bad = 1);
            if (r->bad || (uint64_t)(r->end - r->p) < n) { r->bad = 1; return; }
            buf = r->p; nbuf = (size_t)n; r->p += n;
        } else {
            skip(r, 1);
        }
    }
    emit(o, "\"hex\": \"");
    for (size_t i = 0; i < nbuf && i < 4096; i++) emit(o, "%02x", buf[i]);
    emit(o, "\"}");
}

static int print_message(zmq_msg_t *frames, int nframes) {
    static char line[16384];
    out_t o = {line, line + sizeof line};
    rd_t r = {zmq_msg_data(&frames[1]), (const uint8_t *)zmq_msg_data(&frames[1]) + zmq_msg_size(&frames[1]), 0};
    int is_map;
    int64_t count = get_container(&r, &is_map);
    if (!is_map || r.bad) return -1;
    emit(&o, "{\"topic\": ");
    emit_str(&o, zmq_msg_data(&frames[0]), (uint32_t)zmq_msg_size(&frames[0]));
    emit(&o, ", \"frames\": %d", nframes);
    for (int64_t i = 0; i < count && !r.bad; i++) {
        const char *k; uint32_t kn;
        if (!get_str(&r, &k, &kn)) break;
        if (key_is(k, kn, "type") || key_is(k, kn, "frame_id")) {
            const char *s; uint32_t n;
            if (!get_str(&r, &s, &n)) break;
            emit(&o, ", "); emit_str(&o, k, kn); emit(&o, ": "); emit_str(&o, s, n);
        } else if (key_is(k, kn, "seq") || key_is(k, kn, "stamp_ns")) {
            int is_int; int64_t v;
            get_number(&r, &is_int, &v);
            if (!is_int) r.bad = 1;
            emit(&o, ", "); emit_str(&o, k, kn); emit(&o, ": %lld", (long long)v);
        } else if (key_is(k, kn, "data")) {
            int t = r.p < r.end ? *r.p : -1;
            emit(&o, ", \"data\": ");
            if ((t >= 0x80 && t <= 0x8f) || t == 0xde || t == 0xdf) {
                int64_t n = get_container(&r, &is_map);
                emit_array(&o, &r, n, frames, nframes);
            } else {
                int is_int; int64_t v;
                double d = get_number(&r, &is_int, &v);
                if (is_int) emit(&o, "%lld", (long long)v); else emit(&o, "%.17g", d);
            }
        } else {
            skip(&r, 1);
        }
    }
    if (r.bad) return -1;
    printf("%s}\n", line);
    fflush(stdout);
    return 0;
}

/* -- the runtime directory and the registry (docs/wire.md 6) ------------------------------- */
static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

static uint64_t wall_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return (uint64_t)ts.tv_sec * 1000000000ULL + (uint64_t)ts.tv_nsec;
}

static int runtime_dir(char *out, size_t n) {
    const char *env = getenv("TETHER_RUNTIME_DIR");
    const char *tmp = getenv("TMPDIR");
    if (env && *env) snprintf(out, n, "%s", env);
    else snprintf(out, n, "%s/tether-%u", tmp && *tmp ? tmp : "/tmp", (unsigned)getuid());
    if (mkdir(out, 0700) != 0 && errno != EEXIST) return -1;
    struct stat st;
    if (lstat(out, &st) != 0 || !S_ISDIR(st.st_mode) || st.st_uid != getuid() || (st.st_mode & 022)) {
        fprintf(stderr, "wire_client: runtime directory %s is not a directory private to this user\n", out);
        return -1;
    }
    return 0;
}

static int safe_topic(const char *t) {
    for (; *t; t++)
        if (!(*t == '/' || *t == '_' || *t == '-' || *t == '.' || (*t >= '0' && *t <= '9') ||
              (*t >= 'a' && *t <= 'z') || (*t >= 'A' && *t <= 'Z'))) return 0;
    return 1;
}

int main(int argc, char **argv) {
    if (argc < 5) {
        fprintf(stderr, "usage: %s PUB_TOPIC SUB_ENDPOINT SUB_TOPIC [SUB_TOPIC ...] COUNT\n", argv[0]);
        return 2;
    }
    const char *pub_topic = argv[1], *sub_endpoint = argv[2];
    int ntopics = argc - 4, want = atoi(argv[argc - 1]);
    if (ntopics > MAX_TOPICS || want <= 0 || !safe_topic(pub_topic)) {
        fprintf(stderr, "wire_client: at most %d topics, COUNT > 0, topics of [A-Za-z0-9/_.-]\n", MAX_TOPICS);
        return 2;
    }
    char rt[512], endpoint[700], entry[700], tmp[760];
    if (runtime_dir(rt, sizeof rt) != 0) return 1;
    snprintf(tmp, sizeof tmp, "%s/s", rt);
    mkdir(tmp, 0700);
    snprintf(tmp, sizeof tmp, "%s/graphs", rt);
    mkdir(tmp, 0700);
    snprintf(endpoint, sizeof endpoint, "ipc://%s/s/wirec.%d", rt, (int)getpid());

    void *ctx = zmq_ctx_new();
    void *pub = zmq_socket(ctx, ZMQ_PUB);
    void *sub = zmq_socket(ctx, ZMQ_SUB);
    if (zmq_bind(pub, endpoint) != 0 || zmq_connect(sub, sub_endpoint) != 0) {
        fprintf(stderr, "wire_client: %s\n", zmq_strerror(zmq_errno()));
        return 1;
    }
    for (int i = 0; i < ntopics; i++) zmq_setsockopt(sub, ZMQ_SUBSCRIBE, argv[3 + i], strlen(argv[3 + i]));

    /* Register after binding, atomically: a temporary file renamed into place. */
    snprintf(entry, sizeof entry, "%s/graphs/wirec-%d.local.%d.json", rt, (int)getpid(), (int)getpid());
    snprintf(tmp, sizeof tmp, "%s/graphs/.wirec-%d.tmp", rt, (int)getpid());
    FILE *fh = fopen(tmp, "w");
    if (!fh) { perror(tmp); return 1; }
    fprintf(fh, "{\"name\": \"wirec-%d\", \"machine\": \"\", \"nodes\": {}, \"pid\": %d, \"topics\": "
                "{\"%s\": {\"type\": \"std.Float64\", \"endpoint\": \"%s\"}}}", (int)getpid(), (int)getpid(),
            pub_topic, endpoint);
    fclose(fh);
    chmod(tmp, 0600);
    rename(tmp, entry);

    int got[MAX_TOPICS] = {0}, bad = 0, status = 1;
    uint64_t seq = 0;
    double deadline = now_s() + 30.0, next_pub = 0.0;
    uint8_t body[128];
    zmq_msg_t frames[MAX_FRAMES];
    for (;;) {
        int done = 1;
        for (int i = 0; i < ntopics; i++) done &= got[i] >= want;
        if (done) { status = 0; break; }
        if (now_s() > deadline) { fprintf(stderr, "wire_client: timed out\n"); break; }
        if (now_s() >= next_pub) {
            seq++;
            size_t n = float64_body(body, (double)seq, wall_ns(), seq);
            zmq_send(pub, pub_topic, strlen(pub_topic), ZMQ_SNDMORE);      /* frame 0: the exact topic */
            zmq_send(pub, body, n, 0);                                     /* frame 1: the body */
            next_pub = now_s() + 0.02;
        }
        zmq_pollitem_t item = {sub, 0, ZMQ_POLLIN, 0};
        if (zmq_poll(&item, 1, 10) <= 0) continue;
        int nframes = 0, more = 1;
        while (more) {                                  /* a multipart message arrives whole */
            zmq_msg_t scratch, *m = nframes < MAX_FRAMES ? &frames[nframes] : &scratch;
            zmq_msg_init(m);
            zmq_msg_recv(m, sub, 0);
            more = zmq_msg_more(m);
            if (m == &scratch) zmq_msg_close(m); else nframes++;
        }
        int topic = -1;
        for (int i = 0; i < ntopics; i++)             /* subscriptions match by prefix: compare exactly */
            if (zmq_msg_size(&frames[0]) == strlen(argv[3 + i]) &&
                !memcmp(zmq_msg_data(&frames[0]), argv[3 + i], strlen(argv[3 + i]))) topic = i;
        if (topic >= 0 && (nframes < 2 || nframes == MAX_FRAMES || print_message(frames, nframes) != 0))
            fprintf(stderr, "wire_client: malformed message on %s skipped (%d so far)\n", argv[3 + topic], ++bad);
        else if (topic >= 0)
            got[topic]++;
        for (int i = 0; i < nframes; i++) zmq_msg_close(&frames[i]);
    }
    unlink(entry);
    zmq_close(pub);
    zmq_close(sub);
    zmq_ctx_term(ctx);
    unlink(endpoint + strlen("ipc://"));
    return status;
}
