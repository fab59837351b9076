/*
 * tspend rig end, protocol version 1 (docs/rig.md): the reference firmware of a rig.
 *
 * One file, plain C99, no allocation: every buffer is static.  A microcontroller port
 * supplies the four hw_* functions (encoders, motor, microsecond clock, serial bytes) and
 * calls rig_tick() from a timer at RIG_TICK_US; everything else is portable.  Built with
 * -DRIG_END_HOST (what the tests do) the hw_* functions are a cart-pole simulated in
 * double precision (the ODE of models/cartpole.xml, RK4 per tick) behind a POSIX file
 * descriptor (one end of a pseudo-terminal), so the firmware a lab copies is tested code.
 *
 *   cc -O2 -DRIG_END_HOST -o rig_end rig_end.c -lm
 *   ./rig_end DEVICE_OR_FD [MAX_SECONDS]
 *
 * Doubles travel as IEEE 754 binary64, little-endian (a part whose `double` is 32 bits
 * must pack the command's bits itself).
 */
#include <stdint.h>
#include <string.h>

#define RIG_VERSION 1
#define RIG_TICK_US 1000u            /* the rig's own step: 1 ms */
#ifndef RIG_MIN_PERIOD_US              /* -DRIG_MIN_PERIOD_US=1000u: a 1 kHz rig */
#define RIG_MIN_PERIOD_US 2000u
#endif
#define RIG_MAX_PERIOD_US 20000u
#define RIG_WATCHDOG_US 50000u       /* no valid command this long: motor to zero */
#define RIG_HOST_LOST_US 1000000u    /* watchdog tripped and silence this long: session over */
#define RIG_U_LIMIT 2000.0           /* the amplifier's limit on |u| (N) */
#define RIG_JOINTS 2
#define RIG_MACHINE "cartpole:slider,hinge"
#define RIG_PI 3.14159265358979323846
static const double counts_per_unit[RIG_JOINTS] = {100000.0, 20000.0 / (2.0 * RIG_PI)};

enum { HEADER = 8, CRC = 4 };
enum { SIZE_HELLO_REQUEST = 16, SIZE_HELLO = 100, SIZE_START = 20, SIZE_SENSOR = 44,
       SIZE_COMMAND = 28, SIZE_STOP = 16, SIZE_QUERY = 16 };
#define HELLO_ANSWERS_QUERY 1u           /* hello flag: a query before START is answered */

/* ---- the hardware: supplied by the port ------------------------------------------ */
static void hw_read_counts(int32_t counts[RIG_JOINTS]);
static void hw_write_motor(double u);
static uint64_t hw_micros(void);
static int hw_serial_read(uint8_t *buf, int room);   /* bytes read now, never blocks */
static void hw_serial_write(const uint8_t *buf, int n);

/* ---- CRC-32 (IEEE 802.3, reflected, as zlib.crc32) -------------------------------- */
static uint32_t crc32(const uint8_t *p, int n) {
    uint32_t c = 0xFFFFFFFFu;
    for (int i = 0; i < n; i++) {
        c ^= p[i];
        for (int k = 0; k < 8; k++) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
    }
    return ~c;
}

/* ---- little-endian packing --------------------------------------------------------- */
static void put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put_u32(uint8_t *p, uint32_t v) { for (int i = 0; i < 4; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static void put_u64(uint8_t *p, uint64_t v) { for (int i = 0; i < 8; i++) p[i] = (uint8_t)(v >> (8 * i)); }
static void put_f64(uint8_t *p, double v) { uint64_t b; memcpy(&b, &v, 8); put_u64(p, b); }
static uint32_t get_u32(const uint8_t *p) {
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
}
static double get_f64(const uint8_t *p) {
    uint64_t b = 0; double v;
    for (int i = 7; i >= 0; i--) b = (b << 8) | p[i];
    memcpy(&v, &b, 8);
    return v;
}

/* ---- frames out ---------------------------------------------------------------------- */
static uint8_t out[SIZE_HELLO];

static void send_frame(char type, uint32_t seq, int size) {
    out[0] = 'T'; out[1] = 'S'; out[2] = RIG_VERSION; out[3] = (uint8_t)type;
    put_u32(out + 4, seq);
    put_u32(out + size - CRC, crc32(out, size - CRC));
    hw_serial_write(out, size);
}

static void send_hello(void) {
    memset(out, 0, sizeof out);
    memcpy(out + HEADER, RIG_MACHINE, sizeof RIG_MACHINE - 1);
    out[HEADER + 32] = RIG_JOINTS;
    out[HEADER + 33] = HELLO_ANSWERS_QUERY;
    put_u32(out + HEADER + 36, RIG_MIN_PERIOD_US);
    put_u32(out + HEADER + 40, RIG_MAX_PERIOD_US);
    put_u32(out + HEADER + 44, RIG_WATCHDOG_US);
    put_f64(out + HEADER + 48, RIG_U_LIMIT);
    for (int j = 0; j < RIG_JOINTS; j++) put_f64(out + HEADER + 56 + 8 * j, counts_per_unit[j]);
    send_frame('h', 0, SIZE_HELLO);
}

/* ---- the session's state ------------------------------------------------------------- */
static struct {
    int running, done;
    uint32_t period_ticks, tick, sensor_seq;
    int64_t command_seq;            /* -1: none yet */
    double u;
    uint64_t start_us, last_valid_us, last_heard_us;
    int tripped;
} rig = {0, 0, 1, 0, 0, -1, 0.0, 0, 0, 0, 0};

/* a sensor frame: the time stamp, the last command applied (0xFFFFFFFF: none) */
static void send_counts(uint32_t seq, uint64_t time_us, uint32_t command_seq) {
    int32_t counts[RIG_JOINTS];
    hw_read_counts(counts);
    memset(out, 0, SIZE_SENSOR);
    put_u64(out + HEADER, time_us);
    put_u32(out + HEADER + 8, command_seq);
    put_u16(out + HEADER + 12, (uint16_t)(rig.tripped ? 1 : 0));
    out[HEADER + 14] = RIG_JOINTS;
    for (int j = 0; j < RIG_JOINTS; j++) put_u32(out + HEADER + 16 + 4 * j, (uint32_t)counts[j]);
    send_frame('S', seq, SIZE_SENSOR);
}

static void send_sensor(uint64_t now) {
    send_counts(rig.sensor_seq++, now - rig.start_us, (uint32_t)rig.command_seq);
}

static void on_frame(const uint8_t *f, uint64_t now) {
    uint32_t seq = get_u32(f + 4);
    rig.last_heard_us = now;
    switch (f[3]) {
    case 'H':
        send_hello();
        break;
    case 'Q':
        /* before START only: the state read with the motor off, the query's seq echoed */
        if (!rig.running) send_counts(seq, now, 0xFFFFFFFFu);
        break;
    case 'G': {
        uint32_t period = get_u32(f + HEADER);
        if (period < RIG_MIN_PERIOD_US || period > RIG_MAX_PERIOD_US || period % RIG_TICK_US) {
            memset(out, 0, SIZE_STOP);
            put_u32(out + HEADER, 4);            /* reason 4: period refused */
            send_frame('X', 0, SIZE_STOP);
            break;
        }
        rig.period_ticks = period / RIG_TICK_US;
        rig.running = 1; rig.tick = 0; rig.sensor_seq = 0; rig.command_seq = -1; rig.u = 0.0;
        rig.start_us = rig.last_valid_us = now;
        break;
    }
    case 'C':
        /* a newer command, or the host's own zero (flag 1): applied at once */
        if ((int64_t)seq > rig.command_seq || (get_u32(f + HEADER + 12) & 1u)) {
            rig.u = get_f64(f + HEADER);
            if (rig.u != rig.u) rig.u = 0.0;     /* NaN: never applied */
            rig.command_seq = seq;
        }
        rig.last_valid_us = now;
        break;
    case 'X':
        rig.u = 0.0; rig.running = 0; rig.done = 1;
        hw_write_motor(0.0);
        break;
    }
}

/* ---- frames in: a byte stream cut by the header, resynchronised on any bad byte ---- */
static uint8_t in[2 * SIZE_HELLO];
static int in_len;

static int frame_size(uint8_t type) {
    switch (type) {
    case 'H': return SIZE_HELLO_REQUEST;
    case 'G': return SIZE_START;
    case 'C': return SIZE_COMMAND;
    case 'X': return SIZE_STOP;
    case 'Q': return SIZE_QUERY;
    default: return 0;                            /* not a frame a rig receives */
    }
}

static void drop(int n) { memmove(in, in + n, (size_t)(in_len - n)); in_len -= n; }

static void read_frames(uint64_t now) {
    int got = hw_serial_read(in + in_len, (int)sizeof in - in_len);
    if (got > 0) in_len += got;
    while (in_len >= HEADER) {
        int size = frame_size(in[3]);
        if (in[0] != 'T' || in[1] != 'S' || in[2] != RIG_VERSION || size == 0) { drop(1); continue; }
        if (in_len < size) break;
        if (crc32(in, size - CRC) != get_u32(in + size - CRC)) { drop(1); continue; }  /* corrupt: never applied */
        on_frame(in, now);
        drop(size);
    }
}

/* ---- one tick: read, watchdog, sample, drive ------------------------------------------ */
static void rig_tick(void) {
    uint64_t now = hw_micros();
    read_frames(now);
    if (!rig.running) return;
    /* the watchdog arms on the first command */
    rig.tripped = rig.command_seq >= 0 && now - rig.last_valid_us > RIG_WATCHDOG_US;
    if ((rig.tripped || rig.command_seq < 0) && now - rig.last_heard_us > RIG_HOST_LOST_US) {
        rig.running = 0; rig.done = 1;
    }
    if (rig.tick % rig.period_ticks == 0) send_sensor(now);
    rig.tick++;
    double u = rig.tripped ? 0.0 : rig.u;
    hw_write_motor(u > RIG_U_LIMIT ? RIG_U_LIMIT : (u < -RIG_U_LIMIT ? -RIG_U_LIMIT : u));
}

#ifdef RIG_END_HOST
/* ---- the host build: a simulated cart-pole behind a file descriptor ------------------ */
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <sched.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include <unistd.h>

static int fd = -1;
/* models/cartpole.xml: M = 10 kg, m = 1 kg, l = 3 m (half the pole), g = 9.8 */
static const double M = 10.0, m = 1.0, l = 3.0, g = 9.8;
static double x[4] = {0.0, 0.10471975511965977, 0.0, 0.0};   /* slider, hinge, their rates */

static void derivative(const double s[4], double u, double ds[4]) {
    double sn = sin(s[1]), cs = cos(s[1]), w = s[3];
    double th = (m * l * w * w * sn * cs - (M + m) * g * sn - u * cs)
                / (m * l * cs * cs - 4.0 / 3.0 * l * (M + m));
    ds[0] = s[2]; ds[1] = w;
    ds[2] = (u + m * l * (cs * th - sn * w * w)) / (M + m);
    ds[3] = th;
}

static void hw_write_motor(double u) {   /* the amplifier drives the cart over one tick */
    double h = RIG_TICK_US * 1e-6, k1[4], k2[4], k3[4], k4[4], s[4];
    if (!rig.running) return;
    derivative(x, u, k1);
    for (int i = 0; i < 4; i++) s[i] = x[i] + 0.5 * h * k1[i];
    derivative(s, u, k2);
    for (int i = 0; i < 4; i++) s[i] = x[i] + 0.5 * h * k2[i];
    derivative(s, u, k3);
    for (int i = 0; i < 4; i++) s[i] = x[i] + h * k3[i];
    derivative(s, u, k4);
    for (int i = 0; i < 4; i++) x[i] += h / 6.0 * (k1[i] + 2 * k2[i] + 2 * k3[i] + k4[i]);
}

static void hw_read_counts(int32_t counts[RIG_JOINTS]) {
    for (int j = 0; j < RIG_JOINTS; j++) counts[j] = (int32_t)lround(x[j] * counts_per_unit[j]);
}

static uint64_t hw_micros(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)t.tv_sec * 1000000u + (uint64_t)t.tv_nsec / 1000u;
}

static int hw_serial_read(uint8_t *buf, int room) {
    ssize_t n = room > 0 ? read(fd, buf, (size_t)room) : 0;
    return n > 0 ? (int)n : 0;    /* EAGAIN, or EIO before the host opened its end */
}

static void hw_serial_write(const uint8_t *buf, int n) {
    while (n > 0) {
        ssize_t w = write(fd, buf, (size_t)n);
        if (w < 0 && errno != EAGAIN && errno != EINTR) return;
        if (w > 0) { buf += w; n -= (int)w; }
    }
}

int main(int argc, char **argv) {
    if (argc < 2) { fprintf(stderr, "usage: rig_end DEVICE_OR_FD [MAX_SECONDS]\n"); return 2; }
    char *end;
    long as_fd = strtol(argv[1], &end, 10);
    fd = *end == '\0' ? (int)as_fd : open(argv[1], O_RDWR | O_NOCTTY);
    if (fd < 0) { perror(argv[1]); return 2; }
    fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
    struct sched_param fifo = {.sched_priority = 40};   /* a timer ISR's punctuality, where allowed */
    if (sched_setscheduler(0, SCHED_FIFO, &fifo) != 0) fprintf(stderr, "rig_end: SCHED_FIFO not allowed; ticks may be late\n");
    double max_s = argc > 2 ? atof(argv[2]) : 60.0;
    uint64_t begin = hw_micros();
    struct timespec next;
    clock_gettime(CLOCK_MONOTONIC, &next);
    while (!rig.done && hw_micros() - begin < (uint64_t)(max_s * 1e6)) {
        rig_tick();
        next.tv_nsec += RIG_TICK_US * 1000;
        if (next.tv_nsec >= 1000000000L) { next.tv_nsec -= 1000000000L; next.tv_sec++; }
        clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &next, NULL);
    }
    printf("rig_end: %s; slider %.6f m, hinge %.6f rad, command %.6f\n",
           rig.done ? "stopped" : "time limit", x[0], x[1], rig.u);
    return 0;
}
#endif
