#pragma once
#include <stdint.h>
/* eventtrigger.h: an event with one payload field (the firmware's macro takes up to
 * several (type, name) pairs; types uint8 .. uint32, int8 .. int32, float). */
typedef struct { const char *name; void *payload; } eventTrigger_t;
#define EVENTTRIGGER(NAME, TYPE, FIELD)                                                   \
    static struct { TYPE##_t FIELD; } eventTrigger_##NAME##_payload;                      \
    static eventTrigger_t eventTrigger_##NAME = {#NAME, &eventTrigger_##NAME##_payload};
void eventTrigger(const eventTrigger_t *event);
