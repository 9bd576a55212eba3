# shellcheck shell=bash
# The project's environment for this shell:  source env.sh
#  - the .venv made by `make setup` (ROS 2 Jazzy wheels, or a sourced system Jazzy + pip deps);
#  - the colcon install/ (so `clis`, `ros2 run <pkg> <exe>` and the ament index work);
#  - DDS kept on this machine (loopback Fast DDS profile); opt out with CLIS_NETWORK=1.
_clis_root="$(cd "$(dirname "${BASH_SOURCE[0]:-$0}")" && pwd)"
if [ -f "$_clis_root/.venv/bin/activate" ] && [ "${VIRTUAL_ENV:-}" != "$_clis_root/.venv" ]; then
  # shellcheck disable=SC1091
  source "$_clis_root/.venv/bin/activate"
fi
if [ "${ROS_DISTRO:-}" != "jazzy" ]; then
  # The venv prefix is the ROS underlay when rclpy comes from PyPI wheels (docs/design.md §8).
  case ":${AMENT_PREFIX_PATH:-}:" in
    *":$_clis_root/.venv:"*) ;;
    *) export AMENT_PREFIX_PATH="$_clis_root/.venv${AMENT_PREFIX_PATH:+:$AMENT_PREFIX_PATH}" ;;
  esac
fi
if [ -f "$_clis_root/install/setup.bash" ]; then
  # shellcheck disable=SC1091
  source "$_clis_root/install/setup.bash"
else
  echo "env.sh: no install/ yet: run 'make setup' first" >&2
fi
if [ -z "${CLIS_NETWORK:-}" ]; then
  export FASTRTPS_DEFAULT_PROFILES_FILE="${FASTRTPS_DEFAULT_PROFILES_FILE:-$_clis_root/config/fastdds_loopback.xml}"
  export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
fi
# One BLAS thread per process: the project parallelises with processes (experiment workers,
# one node per process), and OpenBLAS threads on top oversubscribe the cores.
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}" OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
export CLIS_CONFIG_DIR="${CLIS_CONFIG_DIR:-$_clis_root/config}"
unset _clis_root
