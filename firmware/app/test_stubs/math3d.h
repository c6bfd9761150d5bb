#pragma once
struct vec { float x; float y; float z; };
struct quat { float x; float y; float z; float w; };
