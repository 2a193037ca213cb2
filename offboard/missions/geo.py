"""Latitude/longitude/altitude <-> local NED about a home position.

The projection is PX4's (``lib/geo``, ``MapProjection::project`` / ``reproject``): azimuthal
equidistant on a sphere of radius 6 371 000 m, tangent at the home position. Distances and
bearings from home are exact on that sphere; over a mission's few hundred metres the
difference to the WGS-84 ellipsoid is well under a centimetre in shape (a scale error of
at most 0.3 %, the same one PX4 itself makes). Altitudes: NED down is minus the height above
the home's altitude. ``global_from_ned`` inverts ``ned_from_global`` to rounding error, so
waypoint files round-trip.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

#: CONSTANTS_RADIUS_OF_EARTH of PX4 (m).
EARTH_RADIUS_M = 6_371_000.0


@dataclass(frozen=True)
class LocalProjection:
    """Local tangent plane at ``(lat_deg, lon_deg)``, with heights relative to ``alt_m`` (AMSL)."""

    lat_deg: float
    lon_deg: float
    alt_m: float = 0.0

    def ned_from_global(self, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
        """(north, east, down) in metres of a point with AMSL altitude ``alt_m``."""
        north, east = self.north_east(lat_deg, lon_deg)
        return north, east, -(alt_m - self.alt_m)

    def north_east(self, lat_deg: float, lon_deg: float) -> tuple[float, float]:
        """Horizontal position (north, east) in metres (PX4 ``MapProjection::project``)."""
        lat0 = math.radians(self.lat_deg)
        lat = math.radians(lat_deg)
        dlon = math.radians(lon_deg - self.lon_deg)
        sin_lat0, cos_lat0 = math.sin(lat0), math.cos(lat0)
        sin_lat, cos_lat = math.sin(lat), math.cos(lat)
        cos_dlon = math.cos(dlon)
        arg = min(1.0, max(-1.0, sin_lat0 * sin_lat + cos_lat0 * cos_lat * cos_dlon))
        c = math.acos(arg)
        k = c / math.sin(c) if c != 0.0 else 1.0
        north = k * (cos_lat0 * sin_lat - sin_lat0 * cos_lat * cos_dlon) * EARTH_RADIUS_M
        east = k * cos_lat * math.sin(dlon) * EARTH_RADIUS_M
        return north, east

    def global_from_ned(self, north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, alt_m AMSL) of a local point (PX4 ``MapProjection::reproject``)."""
        x = north_m / EARTH_RADIUS_M
        y = east_m / EARTH_RADIUS_M
        c = math.hypot(x, y)
        alt = self.alt_m - down_m
        if c == 0.0:
            return self.lat_deg, self.lon_deg, alt
        lat0 = math.radians(self.lat_deg)
        sin_lat0, cos_lat0 = math.sin(lat0), math.cos(lat0)
        sin_c, cos_c = math.sin(c), math.cos(c)
        lat = math.asin(cos_c * sin_lat0 + x * sin_c * cos_lat0 / c)
        lon = math.radians(self.lon_deg) + math.atan2(y * sin_c, c * cos_lat0 * cos_c - x * sin_lat0 * sin_c)
        lon_deg = math.degrees(lon)
        if not -180.0 <= lon_deg <= 180.0:
            lon_deg = (lon_deg + 180.0) % 360.0 - 180.0
        return math.degrees(lat), lon_deg, alt


def mission_offset_ned(mission_home: tuple[float, float, float], vehicle_home: tuple[float, float, float],
                       home_local_ned_m: tuple[float, float, float]) -> tuple[float, float, float]:
    """Where a mission's local origin lies in the vehicle's local NED frame (m).

    The mission's origin is its home (lat deg, lon deg, alt m AMSL); the vehicle reports its
    home's (lat, lon, alt) and the home's local position (HOME_POSITION x, y, z). Heights in a
    waypoint file are relative to home, so vertically the mission's origin is the vehicle's home
    (its local down), whatever the two AMSL altitudes.
    """
    north, east = LocalProjection(vehicle_home[0], vehicle_home[1]).north_east(mission_home[0], mission_home[1])
    return (north + home_local_ned_m[0], east + home_local_ned_m[1], home_local_ned_m[2])
