"""cikan_ros: learned Time Shift Governors for spacecraft rendezvous (library, runs without ROS).

Internal units are km, s, km/s, km/s^2 in the Earth-centred inertial (ECI) frame; ROS messages use
SI units and are converted only in ``cikan_ros.ros``.
"""

__version__ = "0.1.0"

from .kernel_cache import use_source_keyed_cache

# Before any kernel module imports numba: compiled kernels cached per version of their sources
# (cikan_ros.kernel_cache; NUMBA_CACHE_DIR, when set, wins).
use_source_keyed_cache()
