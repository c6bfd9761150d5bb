/* ns2_hil.c - see ns2_hil.h.  No dynamic memory; every read is bounds-checked. */
#include <string.h>

#include "ns2_hil.h"

uint16_t ns2_hil_crc16(const uint8_t *data, uint16_t n, uint16_t crc)
{
    for (uint16_t i = 0; i < n; ++i) {
        crc = (uint16_t)(crc ^ (uint16_t)((uint16_t)data[i] << 8));
        for (int b = 0; b < 8; ++b) {
            const uint16_t shifted = (uint16_t)((uint32_t)crc << 1);
            crc = (crc & 0x8000u) ? (uint16_t)(shifted ^ 0x1021u) : shifted;
        }
    }
    return crc;
}

void ns2_hil_init(ns2_hil_t *h, ns2_hil_write_fn write)
{
    memset(h, 0, sizeof *h);
    h->write = write;
}

static uint16_t get_u16(const uint8_t *p)
{
    return (uint16_t)(p[0] | (uint16_t)(p[1] << 8));
}

static void put_u16(uint8_t *p, uint16_t v)
{
    p[0] = (uint8_t)(v & 0xFFu);
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
    put_u16(p, (uint16_t)(v & 0xFFFFu));
    put_u16(p + 2, (uint16_t)(v >> 16));
}

static float get_f32(const uint8_t *p)
{
    float f;
    const uint32_t u = (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) | ((uint32_t)p[3] << 24);
    memcpy(&f, &u, sizeof f);
    return f;
}

/* Frames sent by the target carry at most NS2_HIL_MAX_REPLY body bytes (a longer
 * PING body is echoed truncated); the length field always matches what is sent. */
static void send(ns2_hil_t *h, uint8_t type, uint16_t seq, const uint8_t *body, uint16_t n)
{
    uint8_t out[4u + 3u + NS2_HIL_MAX_REPLY + 2u];
    if (n > NS2_HIL_MAX_REPLY) {
        n = NS2_HIL_MAX_REPLY;
    }
    const uint16_t len = (uint16_t)(3u + n);
    out[0] = NS2_HIL_SYNC0;
    out[1] = NS2_HIL_SYNC1;
    put_u16(&out[2], len);
    out[4] = type;
    put_u16(&out[5], seq);
    memcpy(&out[7], body, n);
    put_u16(&out[7u + n], ns2_hil_crc16(&out[2], (uint16_t)(2u + len), 0xFFFFu));
    h->write(out, (uint16_t)(9u + n));
}

static void send_error(ns2_hil_t *h, uint16_t seq, uint8_t code)
{
    h->frames_bad++;
    send(h, NS2_HIL_ERROR, seq, &code, 1u);
}

#define NS2_HIL_NB_BYTES (1u + 4u * NS2_INPUT_DIM) /* u8 type, f32 rel[NS2_INPUT_DIM] */
#define NS2_HIL_PAST_BYTES (24u * NS2_HISTORY_LAGS) /* f32 own_past[6 NS2_HISTORY_LAGS] */

static void predict(ns2_hil_t *h, uint16_t seq, const uint8_t *b, uint16_t n)
{
    static ns2_neighbor_t nb[NS2_HIL_MAX_NEIGHBORS];
#if NS2_HISTORY_LAGS > 0
    static float own_past[6u * NS2_HISTORY_LAGS];
#endif
    if (n < 26u + NS2_HIL_PAST_BYTES) {
        send_error(h, seq, NS2_HIL_E_BODY);
        return;
    }
    const uint8_t robot_type = b[0];
    const uint8_t count = b[1];
    if (count > NS2_HIL_MAX_NEIGHBORS || n != (uint16_t)(26u + NS2_HIL_NB_BYTES * count + NS2_HIL_PAST_BYTES)) {
        send_error(h, seq, NS2_HIL_E_BODY);
        return;
    }
    float p[3], v[3];
    for (int a = 0; a < 3; ++a) {
        p[a] = get_f32(&b[2 + 4 * a]);
        v[a] = get_f32(&b[14 + 4 * a]);
    }
    for (uint16_t j = 0; j < count; ++j) {
        const uint8_t *r = &b[26u + NS2_HIL_NB_BYTES * j];
        nb[j].type = r[0];
        for (int a = 0; a < NS2_INPUT_DIM; ++a) {
            nb[j].rel[a] = get_f32(&r[1 + 4 * a]);
        }
    }
    ns2_info_t info;
#if NS2_HISTORY_LAGS > 0
    for (uint32_t a = 0; a < 6u * NS2_HISTORY_LAGS; ++a) {
        own_past[a] = get_f32(&b[26u + NS2_HIL_NB_BYTES * count + 4u * a]);
    }
    const float f = ns2_predict_f32_hist(robot_type, p, v, own_past, nb, count, &info);
    const int16_t q = ns2_predict_q15_hist(robot_type, p, v, own_past, nb, count, &info);
#else
    const float f = ns2_predict_f32(robot_type, p, v, nb, count, &info);
    const int16_t q = ns2_predict_q15(robot_type, p, v, nb, count, &info);
#endif
    uint32_t fbits;
    memcpy(&fbits, &f, sizeof fbits);
    uint8_t out[18];
    put_u32(&out[0], (uint32_t)info.status);
    put_u32(&out[4], fbits);
    put_u16(&out[8], (uint16_t)q);
    put_u16(&out[10], info.n_used);
    put_u16(&out[12], info.n_invalid);
    put_u16(&out[14], info.n_outside);
    put_u16(&out[16], info.n_truncated);
    h->frames_ok++;
    send(h, NS2_HIL_RESULT, seq, out, sizeof out);
}

static void dispatch(ns2_hil_t *h, const uint8_t *payload, uint16_t len)
{
    if (len < 3u) {
        send_error(h, 0xFFFFu, NS2_HIL_E_LENGTH);
        return;
    }
    const uint16_t seq = get_u16(&payload[1]);
    switch (payload[0]) {
    case NS2_HIL_PREDICT:
        predict(h, seq, &payload[3], (uint16_t)(len - 3u));
        break;
    case NS2_HIL_PING:
        h->frames_ok++;
        send(h, NS2_HIL_PONG, seq, &payload[3], (uint16_t)(len - 3u));
        break;
    default:
        send_error(h, seq, NS2_HIL_E_TYPE);
        break;
    }
}

/* One byte into the frame buffer.  Returns 1 when the buffered frame was rejected
 * (bad length or CRC): the caller replays buf[1..fill) to resynchronize. */
static int step(ns2_hil_t *h, uint8_t byte)
{
    if (h->fill == 0u) {
        if (byte == NS2_HIL_SYNC0) {
            h->buf[h->fill++] = byte;
        }
        return 0;
    }
    if (h->fill == 1u) {
        if (byte == NS2_HIL_SYNC1) {
            h->buf[h->fill++] = byte;
        } else {
            h->fill = (byte == NS2_HIL_SYNC0) ? 1u : 0u;
        }
        return 0;
    }
    h->buf[h->fill++] = byte;
    if (h->fill < 4u) {
        return 0;
    }
    const uint16_t len = get_u16(&h->buf[2]);
    if (len > NS2_HIL_MAX_PAYLOAD || len < 3u) {
        send_error(h, 0xFFFFu, NS2_HIL_E_LENGTH);
        return 1;
    }
    if (h->fill < (uint16_t)(6u + len)) {
        return 0;
    }
    const uint16_t crc = get_u16(&h->buf[4u + len]);
    if (crc != ns2_hil_crc16(&h->buf[2], (uint16_t)(2u + len), 0xFFFFu)) {
        send_error(h, 0xFFFFu, NS2_HIL_E_CRC);
        return 1;
    }
    h->fill = 0;
    dispatch(h, &h->buf[4], len);
    return 0;
}

void ns2_hil_feed(ns2_hil_t *h, uint8_t byte)
{
    /* Bytes alive (buffered frame + queue) never exceed sizeof h->buf: a rejected
     * frame of fill bytes gives back fill - 1 bytes to the queue. */
    uint16_t head = 0, tail = 0;
    h->queue[tail++] = byte;
    while (head < tail) {
        if (step(h, h->queue[head++])) {
            const uint16_t back = (uint16_t)(h->fill - 1u);
            const uint16_t rest = (uint16_t)(tail - head);
            memmove(&h->queue[back], &h->queue[head], rest);
            memcpy(h->queue, &h->buf[1], back);
            head = 0;
            tail = (uint16_t)(back + rest);
            h->fill = 0;
        }
    }
}
