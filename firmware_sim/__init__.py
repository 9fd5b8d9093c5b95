"""The simulated north-finder instrument: physics (Earth, turntable, sensor triads) and firmware.

Conventions, stated once for the whole package
----------------------------------------------
Frames
    ``n`` navigation frame, North-West-Up. ``b`` body (base) frame of the instrument: x is the
    reference ("sensitive") axis, y points left, z up. ``m1`` is the sensor frame carried by the
    turntable after it has turned by ``mu`` about body z.
Attitude
    ``alpha`` is the rotation about z_n that takes n to b, positive counter-clockwise seen from
    above (north towards west); then pitch ``theta`` about y, roll ``gamma`` about x (z-y-x order).
    ``mat_nb`` is C_n^b. The public **azimuth is clockwise from true north**:
    ``azimuth = -alpha mod 360``.
Turntable
    ``mu`` turns the sensors about body z, right-handed about up (counter-clockwise from above).
    ``mat_table(mu)`` is C_m^m1 = [[cos mu, sin mu, 0], [-sin mu, cos mu, 0], [0, 0, 1]].
Sensors
    Gyros read ``omega_m1 = C_m^m1 C_n^b omega_ie_n`` plus the table rate on z plus errors;
    accelerometers read specific force ``f = C_m^m1 C_n^b (0, 0, +g)`` plus errors (level: z reads +g).
Units
    SI inside (rad, rad/s, m/s^2, s); datasheet units only at the edges, named in the identifier
    (``bias_dph`` deg/h, ``arw_dpsh`` deg/sqrt(h), ``vrw_ug_rthz`` micro-g/sqrt(Hz)), converted
    with the factors of :mod:`northfinder.driver.protocol.units`.
Error terms
    Defined once in :mod:`~northfinder.firmware_sim.error_terms` (SI conversion of a sensor spec,
    flicker noise, temperature, warm-up, impulses, vibration, quantisation) and used by both the
    step-by-step instrument (:mod:`~northfinder.firmware_sim.imu`) and the batch generator
    (:mod:`~northfinder.firmware_sim.batch`).
Randomness
    Every random term draws from a :class:`numpy.random.Generator` passed in; nothing reads the
    wall clock.
"""

from northfinder.firmware_sim.errors import SimConfigError, SimError

__all__ = ["SimConfigError", "SimError"]
