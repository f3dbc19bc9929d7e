#!/usr/bin/env bash
# Quick start, part 1: install, then build a Gazebo world from the bundled Willow Garage map.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/scan2terrain map2world fixtures/maps/map_willow_garage_005/willow-full-0.05.yaml \
  -o demo_world --overwrite "$@"
