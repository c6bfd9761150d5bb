#pragma once
#include <stdint.h>
typedef uint32_t TickType_t;
#define M2T(X) ((TickType_t)(X))
#define T2M(X) ((uint32_t)(X))
