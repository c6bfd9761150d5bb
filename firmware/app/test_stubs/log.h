#pragma once
#define LOG_UINT8 0
#define LOG_UINT32 1
#define LOG_INT32 2
#define LOG_FLOAT 3
#define LOG_GROUP_START(NAME) __attribute__((used)) static const void *const ns2_stub_log_##NAME[] = {
#define LOG_ADD(TYPE, NAME, ADDRESS) (const void *)(ADDRESS),
#define LOG_GROUP_STOP(NAME) 0};
