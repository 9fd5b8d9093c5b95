/* A minimal C host for the north finder's serial protocol (protocol.md 2.2 and 4).
 *
 *   cc -O2 -Wall -Wextra -o nf_host nf_host.c
 *   northfinder sim --pty --warmup 0 &        # prints "pty /dev/pts/N"
 *   ./nf_host /dev/pts/N 200
 *
 * It asks IDENTIFY, waits for READY in the heartbeat, starts the stream, averages SAMPLES samples (checking that the sample counter
 * has no gap), stops the stream and prints one line per fact:
 *   identify model M serial S firmware A.B.C protocol X.Y
 *   samples N first C0 last C1 gaps G
 *   mean gyro_dph X Y Z accel_g X Y Z table_deg A
 * Exit status 0 on success, 1 on a timeout or a gap, 2 on bad arguments.
 * POSIX only (termios); no library beyond libc.
 */
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

enum { T_COMMAND = 1, T_REPLY = 2, T_STATUS = 3, T_IDENTIFY = 4, T_SAMPLE = 5 };
enum { OP_IDENTIFY = 0x01, OP_STREAM_START = 0x20, OP_STREAM_STOP = 0x21 };

static int fd = -1;
static uint8_t tx_seq = 0;

static uint16_t crc16_ccitt_false(const uint8_t *p, size_t n) {
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < n; i++) {
        crc ^= (uint16_t)p[i] << 8;
        for (int b = 0; b < 8; b++)
            crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

static uint32_t u32(const uint8_t *p) { return p[0] | p[1] << 8 | p[2] << 16 | (uint32_t)p[3] << 24; }
static int32_t i32(const uint8_t *p) { return (int32_t)u32(p); }
static double scale(const uint8_t *p) { /* u32 mantissa, i8 exponent */
    double v = u32(p);
    for (int e = (int8_t)p[4]; e < 0; e++) v /= 10.0;
    for (int e = (int8_t)p[4]; e > 0; e--) v *= 10.0;
    return v;
}

static double now_s(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return t.tv_sec + t.tv_nsec * 1e-9;
}

static void send_command(uint8_t opcode, uint8_t seq) {
    uint8_t f[9] = {0xA5, 0x5A, 2, T_COMMAND, tx_seq++, seq, opcode, 0, 0};
    uint16_t crc = crc16_ccitt_false(f + 2, 5);
    f[7] = crc & 0xFF;
    f[8] = crc >> 8;
    if (write(fd, f, sizeof f) != (ssize_t)sizeof f) {
        perror("write");
        exit(1);
    }
}

/* Receive buffer and de-framer (protocol.md 2.2: on a bad length or CRC drop one byte). */
static uint8_t buf[4096];
static size_t have = 0;

/* Wait up to timeout_s for the next frame; return its type and payload (length in *n), or -1. */
static int next_frame(uint8_t *payload, size_t *n, double timeout_s) {
    double deadline = now_s() + timeout_s;
    for (;;) {
        while (have >= 7) {
            size_t i = 0;
            while (i + 1 < have && !(buf[i] == 0xA5 && buf[i + 1] == 0x5A)) i++;
            memmove(buf, buf + i, have - i);
            have -= i;
            if (have < 7) break;
            size_t len = buf[2];
            if (len > 64) { memmove(buf, buf + 1, --have); continue; }
            if (have < len + 7) break;
            uint16_t crc = crc16_ccitt_false(buf + 2, len + 3);
            if ((buf[5 + len] | buf[6 + len] << 8) != crc) { memmove(buf, buf + 1, --have); continue; }
            int type = buf[3];
            memcpy(payload, buf + 5, len);
            *n = len;
            memmove(buf, buf + len + 7, have - len - 7);
            have -= len + 7;
            return type;
        }
        double left = deadline - now_s();
        if (left <= 0) return -1;
        struct pollfd p = {fd, POLLIN, 0};
        if (poll(&p, 1, (int)(left * 1000) + 1) > 0) {
            ssize_t r = read(fd, buf + have, sizeof buf - have);
            if (r > 0) have += (size_t)r;
        }
    }
}

int main(int argc, char **argv) {
    if (argc < 2 || argc > 3) {
        fprintf(stderr, "usage: %s PTY [SAMPLES]\n", argv[0]);
        return 2;
    }
    long want = argc == 3 ? strtol(argv[2], NULL, 10) : 200;
    if (want < 1 || want > 1000000) {
        fprintf(stderr, "%s: SAMPLES must be 1..1000000\n", argv[0]);
        return 2;
    }
    fd = open(argv[1], O_RDWR | O_NOCTTY);
    if (fd < 0) {
        fprintf(stderr, "%s: cannot open %s: %s\n", argv[0], argv[1], strerror(errno));
        return 2;
    }
    struct termios tio;
    if (tcgetattr(fd, &tio) == 0) {
        cfmakeraw(&tio);
        cfsetispeed(&tio, B115200);
        cfsetospeed(&tio, B115200);
        tcsetattr(fd, TCSANOW, &tio);
    }
    tcflush(fd, TCIFLUSH);
    uint8_t p[64];
    size_t n;
    double gyro_scale = 1e-4, accel_scale = 1e-6, angle_scale = 1e-6;

    send_command(OP_IDENTIFY, 1);
    int got_identify = 0;
    double until = now_s() + 5.0;
    while (!got_identify) {
        int t = next_frame(p, &n, until - now_s());
        if (t < 0) { fprintf(stderr, "no IDENTIFY within 5 s\n"); return 1; }
        if (t == T_IDENTIFY && n == 49) {
            char model[8] = {0};
            memcpy(model, p + 14, 7);
            gyro_scale = scale(p + 21);
            accel_scale = scale(p + 28);
            angle_scale = scale(p + 35);
            printf("identify model %s serial %u firmware %u.%u.%u protocol %u.%u\n", model,
                   u32(p + 7), p[2], p[3], p[4], p[0], p[1]);
            got_identify = 1;
        }
    }

    /* Wait for READY (state 2) in the heartbeat (protocol.md 4.6, 5): no stream before it. */
    until = now_s() + 300.0;
    for (;;) {
        int t = next_frame(p, &n, until - now_s());
        if (t < 0) { fprintf(stderr, "the device did not become READY\n"); return 1; }
        if (t == T_STATUS && n == 16 && p[0] == 2) break;
        if (t == T_STATUS && n == 16 && p[0] == 5) { fprintf(stderr, "the device is in FAULT\n"); return 1; }
    }

    send_command(OP_STREAM_START, 2);
    double sum[7] = {0};
    long count = 0, gaps = 0;
    uint32_t first = 0, last = 0;
    until = now_s() + 10.0 + want / 50.0;
    while (count < want) {
        int t = next_frame(p, &n, until - now_s());
        if (t < 0) { fprintf(stderr, "stream stopped after %ld samples\n", count); return 1; }
        if (t == T_REPLY && n >= 3 && p[1] == OP_STREAM_START && p[2] != 0) {
            fprintf(stderr, "STREAM_START refused: result %u\n", p[2]);
            return 1;
        }
        if (t != T_SAMPLE || n != 35) continue;
        uint32_t c = u32(p);
        if (count == 0) first = c;
        else if (c != last + 1) gaps += (long)(c - last - 1);
        last = c;
        for (int k = 0; k < 6; k++) sum[k] += i32(p + 4 + 4 * k);
        sum[6] += u32(p + 28);
        count++;
    }
    send_command(OP_STREAM_STOP, 3);
    printf("samples %ld first %u last %u gaps %ld\n", count, first, last, gaps);
    printf("mean gyro_dph %.6f %.6f %.6f accel_g %.7f %.7f %.7f table_deg %.6f\n",
           sum[0] / count * gyro_scale, sum[1] / count * gyro_scale, sum[2] / count * gyro_scale,
           sum[3] / count * accel_scale, sum[4] / count * accel_scale,
           sum[5] / count * accel_scale, sum[6] / count * angle_scale);
    close(fd);
    return gaps ? 1 : 0;
}
