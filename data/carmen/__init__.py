"""CARMEN log files: a streaming reader (`CarmenLog`) and a writer (`write_log`).

Modules: `parsing` (one message line), `geometry` (beam angles, maximum range,
laser mounting), `sniff` (is this a CARMEN log?), `stream` (lines to scans),
`reader` (`CarmenLog`), `writer` (`write_log`).  Import from `data.carmen`.

A CARMEN log ("carmen log file", ``.clf`` / ``.log``; plain, gzip or bzip2, told
apart by magic bytes) holds one message per line::

    message_name [message contents] ipc_timestamp ipc_hostname logger_timestamp

Units: metres, radians, seconds.  ``ipc_timestamp`` is the time the message was
made (used as `Scan.stamp`); ``logger_timestamp`` is the time the logger received
it (ignored).  Lines starting with ``#`` are comments.  The formats below were
checked against CARMEN's ``readlog.c`` / ``writelog.c`` (``src/logtools``) and the
SICK driver (``src/laser``).

Messages read
-------------
``PARAM name value [ipc_timestamp] hostname logger_timestamp``
    A parameter of CARMEN's ``.ini``.  Only the name and the first value token
    are used.  Honoured names (all optional):

    - ``robot_front_laser_max`` / ``robot_rear_laser_max`` [m]: no-return value
      of ``FLASER`` / ``RLASER`` (readings ``>=`` it are invalid).
    - ``laser_front_laser_fov`` / ``laser_rear_laser_fov`` [deg] and
      ``laser_front_laser_resolution`` / ``laser_rear_laser_resolution`` [deg]:
      beam geometry of ``FLASER`` / ``RLASER`` (see *Angles*).
    - ``robot_frontlaser_offset`` (x, forward) [m], ``robot_frontlaser_side_offset``
      (y, left) [m], ``robot_frontlaser_angular_offset`` [rad]: mounting of
      laser 1 on the robot, used to turn interpolated ``ODOM`` poses into laser
      poses for ``RAWLASER1``.  ``robot_rearlaser_offset`` [m]: the rear laser
      (``RAWLASER2``) sits that far *behind* the robot centre looking backwards,
      pose ``(-offset, 0, pi)`` in the robot frame, as CARMEN's localizer does.

    A ``PARAM`` applies to the laser messages after it (CARMEN writes them first).

``ODOM x y theta tv rv accel ipc_timestamp hostname logger_timestamp``
    Wheel odometry pose of the robot centre (m, m, rad) and velocities.

``FLASER`` / ``RLASER`` (front / rear laser, old format)::

    num_readings range[num_readings] x y theta odom_x odom_y odom_theta
    ipc_timestamp hostname logger_timestamp

    ``x y theta`` is the pose of the laser (`Scan.odom`); in the GMapping-corrected
    logs it is the corrected pose.  ``odom_*`` is the robot's odometry (unused).

``ROBOTLASER1`` / ``ROBOTLASER2``::

    laser_type start_angle field_of_view angular_resolution maximum_range
    accuracy remission_mode num_readings range[num_readings] num_remissions
    remission[num_remissions] laser_pose_x laser_pose_y laser_pose_theta
    robot_pose_x robot_pose_y robot_pose_theta laser_tv laser_rv
    forward_safety_dist side_safety_dist turn_axis ipc_timestamp hostname
    logger_timestamp

    `Scan.odom` is the laser pose.  Logs of old CARMEN versions lack
    ``remission_mode``; both layouts are accepted (the one whose counts match the
    line wins).

``RAWLASER1`` .. ``RAWLASER4`` (the laser driver's own message, no pose)::

    laser_type start_angle field_of_view angular_resolution maximum_range
    accuracy remission_mode num_readings range[num_readings] num_remissions
    remission[num_remissions] ipc_timestamp hostname logger_timestamp

    `Scan.odom` is the robot's ``ODOM`` pose interpolated to the scan stamp
    (`data.se2.interpolate` between the ODOM messages just before and just after
    the scan in file order; the nearer one in time when their stamps run
    backwards; the nearest one at the ends of the log), composed with the laser
    mounting from ``PARAM`` (above; identity for ``RAWLASER3``/``4``).  The reader
    holds the scans that wait for the next ``ODOM`` (at most 2,000; beyond that
    they take the last ODOM pose).  With no ``ODOM`` in the log, `Scan.odom` is
    None.

Every other message (``NEFF``, ``SYNC``, ``TRUEPOS``, ``NMEA...``, ...) is
skipped silently, and so are laser messages of a kind other than the selected one.

Which laser
-----------
``laser="auto"`` takes the kind of the first laser message in the file (file
order: whichever of ``FLASER``, ``RLASER``, ``ROBOTLASER1/2``, ``RAWLASER1..4``
comes first); ``laser="RLASER"`` (any listed name) selects that one.  A selected
kind absent from the whole file is a `DataError` at the end of the iteration.

Angles
------
Beam ``i`` has bearing ``start_angle + i * angular_resolution`` (CARMEN's
convention: angles of beam *centres*, the first at ``start_angle``; CARMEN's
``field_of_view`` is first-to-last, ``(n - 1) * angular_resolution``).
``ROBOTLASER``/``RAWLASER`` carry these fields; when ``angular_resolution`` is
not positive, ``field_of_view / (n - 1)`` is used.

``FLASER``/``RLASER`` carry none.  With ``laser_*_laser_resolution`` (deg) in the
log's PARAMs: that step, the first beam at ``-fov / 2`` (``fov`` from
``laser_*_laser_fov`` [deg], default 180), used when ``n`` beams fit the fov
(``(n - 1) * step`` within one step below ``fov``: e.g. 360 beams at 0.5 deg span
-90..+89.5 deg as CARMEN's SICK driver says), otherwise ignored.  With
``laser_*_laser_fov`` alone: ``n`` beams evenly from ``-fov/2`` to ``+fov/2``.
Otherwise CARMEN's own default (``readlog.c`` and its SICK driver): a 180-degree
fov and a step of ``fov / n`` for an even ``n`` or ``fov / (n - 1)`` for an odd
``n``, the first beam at -90 degrees; so 180 beams span -90..+89 degrees in 1
degree steps (the SICK's last beam dropped), 181 beams -90..+90, 360 beams
-90..+89.5.  Some notes on the Intel data set give a step of pi/179 instead;
the reader keeps CARMEN's default, which CARMEN's tools (with which the Intel
relations were made) use too.  `old_laser_geometry` is the one place to change.

Maximum range
-------------
`Scan.max_range` is the no-return threshold: readings ``>=`` it, NaN, inf and
``<= 0`` are invalid (`Scan.valid`); they are kept raw in `Scan.ranges`.

- ``ROBOTLASER``/``RAWLASER``: ``maximum_range`` of the message (when it is not
  positive: as for ``FLASER``).
- ``FLASER``/``RLASER``: ``robot_front_laser_max`` / ``robot_rear_laser_max``
  from PARAM when present.  Otherwise 80.0 m, CARMEN's own default for these
  messages (SICK LMS in cm mode logs a missing return as 81.83-81.91 m: Intel,
  Freiburg, Seattle), *unless* the log is a SICK in mm mode or a clipped log:
  the reader looks at the first 500 laser messages (holding them back, bounded)
  and, when no reading in them exceeds one of the no-return values
  8.191, 16.383, 32.767 m (SICK 8/16/32 m modes, codes 2^k - 1 mm) or 50.0 m
  (PLS and clipped Radish logs) by more than 5 mm and at least 0.5 % of their
  beams lie in the band just below the smallest such value that is not
  exceeded (12.5 mm wide for the SICK modes, 5 mm for 50.0), the band's lower
  edge becomes the maximum range (32.7545 m for Orebro's 32.76/32.77 m
  no-returns).
- ``max_range=`` given to `CarmenLog` overrides all of this.

Bad input
---------
A missing file, a directory, an empty file or one whose first lines are not
CARMEN messages raise `DataError` ("not a CARMEN log: ...").  A malformed line
of a message the reader uses (wrong count of fields, no range reading, a number
that does not parse, a non-finite pose or stamp, a line cut short, a first token
that is no message name) is skipped; at the end of the iteration one warning
gives the count and the first bad line number.  A compressed stream that breaks
off (bzip2/gzip error) ends the iteration after the last good line, with the
same single warning.  ``strict=True`` raises `DataError` with the line number
instead.  A line may omit the final logger timestamp.  The reader never sorts:
file order is the order of motion (Intel's ipc timestamps run backwards 631
times).
"""

from data.carmen.geometry import (
    DEFAULT_MAX_RANGE,
    NO_RETURN_BANDS,
    choose_max_range,
    field_of_view_deg,
    old_laser_geometry,
)
from data.carmen.parsing import LASER_MESSAGES, OLD_LASERS, RAW_LASERS, ROBOT_LASERS
from data.carmen.reader import CarmenLog
from data.carmen.sniff import is_carmen
from data.carmen.writer import WRITER_LASER_TYPE, write_log

__all__ = [
    "DEFAULT_MAX_RANGE",
    "LASER_MESSAGES",
    "NO_RETURN_BANDS",
    "OLD_LASERS",
    "RAW_LASERS",
    "ROBOT_LASERS",
    "WRITER_LASER_TYPE",
    "CarmenLog",
    "choose_max_range",
    "field_of_view_deg",
    "is_carmen",
    "old_laser_geometry",
    "write_log",
]
