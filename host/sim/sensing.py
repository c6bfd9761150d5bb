"""What a Crazyflie in the paper's setup senses (one mocap marker at 100 Hz, on-board
IMU, on-board EKF), as plain data; every figure's source is in docs/sensing.md.
The C side (host/ns2_fly.c) applies them; this module only holds them and draws the
per-robot biases."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Sensing:
    # motion capture, broadcast to all robots (own position -> EKF, others -> peer table)
    mocap_hz: int = 100                  # paper, "Experimental setup"
    mocap_sd_m: float = 0.001            # per axis, one marker (Vicon: sub-millimetre jitter)
    latency_ms: int = 11                 # Crazyswarm (Preiss et al., ICRA 2017), Fig. 3: 8 ms + 3 ms
    loss: float = 0.05                   # per robot and frame: an assumption (no published figure)
    ext_pos_std_m: float = 0.01          # firmware default locSrv.extPosStdDev (EKF's measurement model)
    # IMU: BMI088 (Crazyflie 2.1), at the bandwidths the firmware configures
    gyro_sd_dps: float = 0.014 * math.sqrt(116.0)   # 0.014 deg/s/sqrt(Hz), BW 116 Hz
    acc_sd_g: float = 175e-6 * math.sqrt(145.0)     # 175 ug/sqrt(Hz), ODR 1600 Hz OSR4: BW 145 Hz
    acc_bias_g: float = 0.020            # zero-g offset, typical, per axis (not calibrated on board)
    gyro_bias_samples: int = 1024        # the firmware's gyro-bias calibration at rest (mean of 1024)

    def biases(self, rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per robot: accelerometer bias (g, uniform within the typical offset), the
        firmware's accScale (|acc| at rest, level: sensors_bmi088_bmp3xx.c processAccScale;
        it divides every sample, which removes most of a z bias) and the gyro bias left
        after the firmware's start-up calibration (deg/s: the error of a mean of
        gyro_bias_samples noisy samples)."""
        acc = rng.uniform(-self.acc_bias_g, self.acc_bias_g, (n, 3))
        scale = np.linalg.norm(acc + [0.0, 0.0, 1.0], axis=1)
        gyro = rng.normal(0.0, self.gyro_sd_dps / math.sqrt(self.gyro_bias_samples), (n, 3))
        return acc, scale, gyro
