/*
 * gli_socket_client: an application that reaches a simulated modem through the uwsimnet socket
 * bridge (docs/bridges.md), in plain C with no library beyond libc.
 *
 *   cc -std=c99 -Wall -O2 -o gli_socket_client gli_socket_client.c
 *   ./gli_socket_client HOST PORT DST COUNT [EXPECT_RX] [TIMEOUT_S] [TEXT]
 *
 * Connects over TCP, reads the bridge's HELLO, sends COUNT frames "<TEXT> #<i>" to address DST
 * (tags 1..COUNT), then prints every frame it receives (RX) and every status of its frames
 * (STATUS) until it has received EXPECT_RX frames (default 0) and seen a final status for each of
 * its frames, or TIMEOUT_S seconds (default 10) pass.  Exit status 0 if EXPECT_RX frames arrived,
 * 2 otherwise, 1 on usage or connection errors.
 *
 * Wire format: u32 BE length | u8 type | fields, all big-endian:
 *   HELLO 1  u16 address | u16 max_payload | id
 *   TX    2  u16 dst | u32 tag | data
 *   RX    3  u16 src | u16 dst | u32 seq | f64 t_tx | f64 t_rx | data
 *   STATUS 4 u32 tag | u8 event | f64 t | reason
 *   ERROR 5  text
 */
#define _POSIX_C_SOURCE 200809L
#include <errno.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <sys/types.h>
#include <time.h>
#include <unistd.h>

#define MAX_BODY (64 + 2048)

static const char *EVENTS[] = {"queued", "sent", "dropped", "acked", "failed", "delivered", "lost",
                               "transmitted"};

static uint16_t get16(const unsigned char *p) { return (uint16_t)((p[0] << 8) | p[1]); }
static uint32_t get32(const unsigned char *p) {
    return ((uint32_t)p[0] << 24) | ((uint32_t)p[1] << 16) | ((uint32_t)p[2] << 8) | p[3];
}
static double getf64(const unsigned char *p) {
    uint64_t u = 0;
    double d;
    for (int i = 0; i < 8; i++) u = (u << 8) | p[i];
    memcpy(&d, &u, sizeof d);
    return d;
}
static void put16(unsigned char *p, uint16_t v) { p[0] = (unsigned char)(v >> 8); p[1] = (unsigned char)v; }
static void put32(unsigned char *p, uint32_t v) {
    p[0] = (unsigned char)(v >> 24); p[1] = (unsigned char)(v >> 16);
    p[2] = (unsigned char)(v >> 8); p[3] = (unsigned char)v;
}

static double now_s(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + ts.tv_nsec / 1e9;
}

static int connect_to(const char *host, const char *port) {
    struct addrinfo hints, *res, *ai;
    int fd = -1;
    memset(&hints, 0, sizeof hints);
    hints.ai_family = AF_UNSPEC;
    hints.ai_socktype = SOCK_STREAM;
    if (getaddrinfo(host, port, &hints, &res) != 0) return -1;
    for (ai = res; ai; ai = ai->ai_next) {
        fd = socket(ai->ai_family, ai->ai_socktype, ai->ai_protocol);
        if (fd < 0) continue;
        if (connect(fd, ai->ai_addr, ai->ai_addrlen) == 0) break;
        close(fd);
        fd = -1;
    }
    freeaddrinfo(res);
    if (fd >= 0) {
        int one = 1;
        setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
    }
    return fd;
}

static int write_all(int fd, const unsigned char *buf, size_t n) {
    while (n > 0) {
        ssize_t w = write(fd, buf, n);
        if (w < 0) {
            if (errno == EINTR) continue;
            return -1;
        }
        buf += w;
        n -= (size_t)w;
    }
    return 0;
}

static void print_data(const unsigned char *d, size_t n) {
    for (size_t i = 0; i < n; i++) {
        if (d[i] >= 0x20 && d[i] < 0x7f && d[i] != '\\') putchar(d[i]);
        else printf("\\x%02x", d[i]);
    }
}

int main(int argc, char **argv) {
    if (argc < 5) {
        fprintf(stderr, "usage: %s HOST PORT DST COUNT [EXPECT_RX] [TIMEOUT_S] [TEXT]\n", argv[0]);
        return 1;
    }
    const char *host = argv[1], *port = argv[2];
    unsigned dst = (unsigned)strtoul(argv[3], NULL, 10);
    int count = atoi(argv[4]);
    int expect_rx = argc > 5 ? atoi(argv[5]) : 0;
    double timeout = argc > 6 ? atof(argv[6]) : 10.0;
    const char *text = argc > 7 ? argv[7] : "hello from C";

    int fd = connect_to(host, port);
    if (fd < 0) {
        fprintf(stderr, "cannot connect to %s:%s: %s\n", host, port, strerror(errno));
        return 1;
    }

    static unsigned char buf[4 + MAX_BODY + 65536];
    size_t have = 0;
    int rx = 0, finals = 0, hello = 0, sent_all = 0;
    double deadline = now_s() + timeout;

    for (;;) {
        /* send our frames once the bridge said hello */
        if (hello && !sent_all) {
            for (int i = 0; i < count; i++) {
                unsigned char msg[4 + 7 + 256];
                int n = snprintf((char *)msg + 11, 256, "%s #%d", text, i + 1);
                if (n < 0 || n >= 256) n = 255;
                put32(msg, (uint32_t)(7 + n));
                msg[4] = 2; /* TX */
                put16(msg + 5, (uint16_t)dst);
                put32(msg + 7, (uint32_t)(i + 1));
                if (write_all(fd, msg, (size_t)(11 + n)) < 0) {
                    fprintf(stderr, "write: %s\n", strerror(errno));
                    return 1;
                }
            }
            sent_all = 1;
            fflush(stdout);
        }
        if (sent_all && rx >= expect_rx && finals >= count) break;
        double left = deadline - now_s();
        if (left <= 0) break;
        struct pollfd p = {fd, POLLIN, 0};
        int r = poll(&p, 1, (int)(left * 1000) + 1);
        if (r < 0 && errno != EINTR) break;
        if (r <= 0) continue;
        ssize_t got = read(fd, buf + have, sizeof buf - have);
        if (got <= 0) {
            fprintf(stderr, "connection closed by the bridge\n");
            break;
        }
        have += (size_t)got;
        /* parse complete messages */
        size_t off = 0;
        while (have - off >= 4) {
            uint32_t n = get32(buf + off);
            if (n == 0 || n > MAX_BODY) {
                fprintf(stderr, "bad message length %u\n", n);
                close(fd);
                return 1;
            }
            if (have - off < 4 + n) break;
            const unsigned char *b = buf + off + 4;
            switch (b[0]) {
            case 1: /* HELLO */
                if (n >= 5) {
                    printf("HELLO address=%u max_payload=%u id=%.*s\n", get16(b + 1), get16(b + 3),
                           (int)(n - 5), (const char *)b + 5);
                    hello = 1;
                }
                break;
            case 3: /* RX */
                if (n >= 25) {
                    printf("RX src=%u dst=%u seq=%u t_tx=%.6f t_rx=%.6f len=%u data=", get16(b + 1),
                           get16(b + 3), get32(b + 5), getf64(b + 9), getf64(b + 17), n - 25);
                    print_data(b + 25, n - 25);
                    putchar('\n');
                    rx++;
                }
                break;
            case 4: /* STATUS */
                if (n >= 14) {
                    unsigned ev = b[5];
                    const char *name = ev < sizeof EVENTS / sizeof *EVENTS ? EVENTS[ev] : "?";
                    printf("STATUS tag=%u event=%s t=%.6f reason=%.*s\n", get32(b + 1), name, getf64(b + 6),
                           (int)(n - 14), (const char *)b + 14);
                    /* a broadcast ends at sent; a unicast at delivered/lost/dropped/failed */
                    if (ev == 2 || ev == 4 || ev == 5 || ev == 6 || (ev == 1 && dst == 255)) finals++;
                }
                break;
            case 5: /* ERROR */
                printf("ERROR %.*s\n", (int)(n - 1), (const char *)b + 1);
                break;
            default:
                printf("UNKNOWN type=%u len=%u\n", b[0], n);
            }
            off += 4 + n;
        }
        memmove(buf, buf + off, have - off);
        have -= off;
        fflush(stdout);
    }
    close(fd);
    printf("DONE rx=%d finals=%d\n", rx, finals);
    return rx >= expect_rx ? 0 : 2;
}
