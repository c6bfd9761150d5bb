/*
 * param_write.h - a parameter write on the host as the firmware's param_logic.c does
 * it (paramWriteProcess: the value copied to the variable, then the entry's callback),
 * on a PARAM group table of the translation unit (PARAM_GROUP_START(g) defines the
 * static array __params_g; entries up to its PARAM_GROUP_STOP).  For the host
 * harnesses, which include the firmware's or the app's .c files.
 */
#ifndef NS2_PARAM_WRITE_H
#define NS2_PARAM_WRITE_H

#include <string.h>

#include "param.h"

/* The entry `name` of the group, NULL if none. */
static struct param_s *param_find(struct param_s *group, const char *name)
{
    for (struct param_s *p = group + 1; p->type != (PARAM_GROUP | PARAM_STOP); ++p) {
        if (strcmp(p->name, name) == 0) {
            return p;
        }
    }
    return NULL;
}

/* 0 written; -1 no such name in the group; -2 read-only or the size differs */
static int param_write(struct param_s *group, const char *name, const void *value, size_t size)
{
    struct param_s *p = param_find(group, name);
    if (p == NULL) {
        return -1;
    }
    if ((p->type & PARAM_RONLY) || size != (size_t)(1u << (p->type & PARAM_BYTES_MASK))) {
        return -2;
    }
    memcpy(p->address, value, size);
    if (p->callback) {
        p->callback();
    }
    return 0;
}

#endif
