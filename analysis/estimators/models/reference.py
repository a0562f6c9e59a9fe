"""Published parameter sets used as simulation defaults and as test oracles.

Nikolic et al. 2016 (IEEE Sensors J. 16(1)), Tables II-IV:
standard noise model (1a) identified with ML_i. Units: sigma_w rad s^-1/sqrt(Hz),
sigma_b rad s^-2/sqrt(Hz), tau_b s.
"""

from __future__ import annotations

from imustation.analysis.estimators.models.standard import StandardModel

#: Table IV, per device and gyro axis
TABLE_IV: dict[str, dict[str, StandardModel]] = {
    "mpu9150": {
        "x": StandardModel(7.28e-5, 1.25e-5, 4.85e3),
        "y": StandardModel(7.47e-5, 8.73e-6, 6.58e3),
        "z": StandardModel(5.83e-5, 3.25e-6, 2.33e3),
    },
    "mpu6500": {
        "x": StandardModel(1.42e-4, 5.66e-6, 1.68e4),
        "y": StandardModel(1.08e-4, 1.09e-5, 5.99e2),
        "z": StandardModel(1.12e-4, 1.42e-5, 5.94e3),
    },
    "bmx055": {
        "x": StandardModel(1.24e-4, 1.65e-6, 5.37e2),
        "y": StandardModel(1.99e-4, 2.41e-6, 2.44e3),
        "z": StandardModel(9.97e-5, 1.20e-6, 6.59e2),
    },
    "mti": {
        "x": StandardModel(1.49e-4, 2.78e-5, 1.49e2),
        "y": StandardModel(2.16e-4, 1.06e-5, 2.05e3),
        "z": StandardModel(1.54e-4, 1.26e-5, 3.11e2),
    },
    "dsp3000": {
        "z": StandardModel(1.56e-5, 2.01e-7, 3.05e3),
    },
    "adis16448": {
        "x": StandardModel(1.75e-4, 1.55e-5, 4.01e2),
        "y": StandardModel(1.64e-4, 1.27e-5, 2.87e2),
        "z": StandardModel(1.73e-4, 1.61e-5, 4.99e2),
    },
}

#: Table III: BMX055 z-gyro, ten 12 h datasets (mean; std in TABLE_III_STD).
#: sigma_w 21.66 deg/h/sqrt(Hz) = 1.050e-4 rad/s/sqrt(Hz).
TABLE_III_MEAN = StandardModel(1.050e-4, 1.26e-6, 530.51)
TABLE_III_STD = StandardModel(0.032e-4, 0.15e-6, 73.90)


# --- accelerometers: NOT from the paper ---------------------------------------
# The paper identifies gyroscopes only. Simulated accelerometers need defaults,
# so these are datasheet-typical noise densities with a small Gauss-Markov bias
# chosen by us (stationary bias std sigma_b * sqrt(tau_b / 2) of about 0.05 mg
# for the BMX055 and 0.1 mg for the InvenSense parts). They are simulation
# defaults only, never test oracles for identification. Units: sigma_w
# m s^-2/sqrt(Hz), sigma_b m s^-3/sqrt(Hz), tau_b s.
#   BMX055 accel output noise density 150 ug/sqrt(Hz) (Bosch BMX055 datasheet, typ.)
#   MPU-6050/9150 accel noise power spectral density 400 ug/sqrt(Hz) (MPU-6050 product spec, typ.)
#   MPU-6500 accel noise power spectral density 300 ug/sqrt(Hz) (MPU-6500 product spec, typ.)
_UG = 9.80665e-6  # m/s^2 per micro-g
_ACCEL_TAU_B = 1000.0
_BMX055_ACCEL = StandardModel(150 * _UG, 50 * _UG / (_ACCEL_TAU_B / 2) ** 0.5, _ACCEL_TAU_B)
_MPU6050_ACCEL = StandardModel(400 * _UG, 100 * _UG / (_ACCEL_TAU_B / 2) ** 0.5, _ACCEL_TAU_B)
_MPU6500_ACCEL = StandardModel(300 * _UG, 100 * _UG / (_ACCEL_TAU_B / 2) ** 0.5, _ACCEL_TAU_B)

#: simulation defaults for accelerometers, per device and axis (see the comment above)
ACCEL_DEFAULTS: dict[str, dict[str, StandardModel]] = {
    "bmx055": dict.fromkeys("xyz", _BMX055_ACCEL),
    "mpu9150": dict.fromkeys("xyz", _MPU6050_ACCEL),
    "mpu6500": dict.fromkeys("xyz", _MPU6500_ACCEL),
}
