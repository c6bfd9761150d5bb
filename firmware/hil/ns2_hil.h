/*
 * ns2_hil.h - framed binary protocol of the serial hardware-in-the-loop image.
 *
 * Frame: 0xA5 0x5A | len (u16 LE) | payload (len bytes) | crc (u16 LE)
 * crc = CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over len and payload.
 * payload[0] = message type, payload[1..2] = sequence number (u16 LE).
 *
 * Requests:  0x01 PREDICT  u8 robot_type, u8 n, f32 p[3], f32 v[3],
 *                          n x (u8 type, f32 rel[NS2_INPUT_DIM]),
 *                          f32 own_past[6 NS2_HISTORY_LAGS]      (all LE, packed)
 *                          (a network without wake memory: rel[6], no own_past;
 *                          with it the *_hist entry points; the payload limit
 *                          bounds n: 9 neighbours with 3 lags)
 *            0x02 PING     any bytes, echoed (the first NS2_HIL_MAX_REPLY of them)
 * Responses: 0x81 RESULT   i32 status, u32 float bits, i16 fixed, u16 n_used,
 *                          u16 n_invalid, u16 n_outside, u16 n_truncated
 *            0x82 PONG     the PING bytes, at most NS2_HIL_MAX_REPLY
 *            0xEE ERROR    u8 code (NS2_HIL_E_*); sequence 0xFFFF when unknown
 * A frame with a bad CRC or length is answered with ERROR and the parser
 * resynchronizes on the next 0xA5 0x5A found after the bad frame's start.
 */
#ifndef NS2_HIL_H
#define NS2_HIL_H

#include <stdint.h>

#include "ns2_deepset.h"

#define NS2_HIL_SYNC0 0xA5u
#define NS2_HIL_SYNC1 0x5Au
#define NS2_HIL_MAX_PAYLOAD 1024u
#define NS2_HIL_MAX_NEIGHBORS 32u
#define NS2_HIL_MAX_REPLY 32u /* body bytes of a frame sent by the target */

#define NS2_HIL_PREDICT 0x01u
#define NS2_HIL_PING 0x02u
#define NS2_HIL_RESULT 0x81u
#define NS2_HIL_PONG 0x82u
#define NS2_HIL_ERROR 0xEEu

#define NS2_HIL_E_CRC 1u
#define NS2_HIL_E_LENGTH 2u
#define NS2_HIL_E_TYPE 3u
#define NS2_HIL_E_BODY 4u

/* Sends n bytes to the host (blocking). */
typedef void (*ns2_hil_write_fn)(const uint8_t *data, uint16_t n);

typedef struct {
    uint8_t buf[4u + NS2_HIL_MAX_PAYLOAD + 2u]; /* sync, len, payload, crc */
    uint8_t queue[4u + NS2_HIL_MAX_PAYLOAD + 2u]; /* bytes replayed after a rejected frame */
    uint16_t fill;                              /* bytes of the frame in buf */
    ns2_hil_write_fn write;
    uint32_t frames_ok;
    uint32_t frames_bad;
} ns2_hil_t;

uint16_t ns2_hil_crc16(const uint8_t *data, uint16_t n, uint16_t crc);
void ns2_hil_init(ns2_hil_t *h, ns2_hil_write_fn write);
/* Feed one received byte; complete frames are answered through h->write. */
void ns2_hil_feed(ns2_hil_t *h, uint8_t byte);

#endif /* NS2_HIL_H */
