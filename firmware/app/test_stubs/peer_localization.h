#pragma once
#include <stdint.h>
#include "math3d.h"
#define PEER_LOCALIZATION_MAX_NEIGHBORS 10
typedef struct peerLocalizationOtherPosition_s {
    uint8_t id;
    uint32_t timestamp; /* ms */
    struct vec pos;
    struct quat orientation;
} peerLocalizationOtherPosition_t;
peerLocalizationOtherPosition_t *peerLocalizationGetPositionByIdx(uint8_t idx);
