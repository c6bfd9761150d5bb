#pragma once
#define PARAM_UINT8 0
#define PARAM_UINT16 1
#define PARAM_UINT32 2
#define PARAM_FLOAT 3
#define PARAM_GROUP_START(NAME) __attribute__((used)) static const void *const ns2_stub_param_##NAME[] = {
#define PARAM_ADD(TYPE, NAME, ADDRESS) (const void *)(ADDRESS),
#define PARAM_GROUP_STOP(NAME) 0};
