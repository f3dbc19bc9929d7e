"""Every path into the real sample files (``fixtures/``) the tests and benchmarks use, in one place.

Each folder's ``SOURCE.txt`` (or ``fixtures/ATTRIBUTION.md``) says where a file comes from and
what is known about it; tests name the files by these constants rather than by a path of their
own, so that a moved or renamed fixture is changed here once.
"""

from __future__ import annotations

from pathlib import Path
from typing import TypedDict

#: The repository's root.
ROOT = Path(__file__).resolve().parent.parent
FIXTURES = ROOT / "fixtures"

# --- bags (fixtures/bags): ROS 1 files, rosbag2 folders ----------------------------------------

BAGS = FIXTURES / "bags"
SICK_ROS1_DIR = BAGS / "bag1_sick_lms1xx_radar_tf"
SICK_ROS1 = SICK_ROS1_DIR / "rms_1xxx_lms_1xx_movement_off.bag"
SICK_DB3 = BAGS / "bag2_derived_sick_lms1xx_db3"
EMBARK_ROS1_DIR = BAGS / "bag1_embark_luminar_pointcloud"
EMBARK_ROS1 = EMBARK_ROS1_DIR / "test.bag"
EMBARK_MCAP = BAGS / "bag2_derived_embark_luminar_mcap"
FUSE_DIR = BAGS / "bag1_fuse_tb3_sim_scan_odom"
FUSE = FUSE_DIR / "turtlebot3.bag"
LEG_TRACKER_DIR = BAGS / "bag1_leg_tracker_room_scan"
LEG_TRACKER = LEG_TRACKER_DIR / "demo_stationary_simple_environment.bag"
CCNY_DIR = BAGS / "bag1_ccny_hokuyo_scan"
CCNY = CCNY_DIR / "demo.bag"
LEGACY = BAGS / "bag1_legacy_rosrecord_v12/demo_rosrecord_v1.2.bag"
GRIDMAP = BAGS / "bag2_gridmap_db3_unknown_type"
NAV2 = BAGS / "bag2_nav2_collision_mcap_zstd"

# --- point clouds (fixtures/clouds) -------------------------------------------------------------

CLOUDS = FIXTURES / "clouds"
HDL_PCD = CLOUDS / "pc_hdl32_scan_pcd_ply_twin/251370668.pcd"
HDL_PLY = CLOUDS / "pc_hdl32_scan_pcd_ply_twin/target.ply"
OFFICE = CLOUDS / "pc_pcl_office1_organized/office1.pcd"
SIMPLE_LAS = CLOUDS / "pc_las_simple_twin/simple.las"
SIMPLE_LAZ = CLOUDS / "pc_las_simple_twin/simple.laz"
AUTZEN = CLOUDS / "pc_laz_autzen_trim/autzen_trim.laz"
AUTZEN_CSV = CLOUDS / "pc_csv_autzen_shuffled_cols/autzen-point-format-3.txt"
STREET = CLOUDS / "pc_xyz_street_lidar/multisensor_lidar.xyz"

# --- occupancy maps (fixtures/maps) and heightmap images (fixtures/images) -----------------------

WILLOW = FIXTURES / "maps/map_willow_garage_005/willow-full-0.05.yaml"
TB3_MAP = FIXTURES / "maps/map_tb3_world_mapsaver/map.yaml"
LEVINE_DIR = FIXTURES / "maps/map_levine_thinwalls"
LEVINE = LEVINE_DIR / "levine.yaml"
WAREHOUSE = FIXTURES / "maps/map_nav2_warehouse_003/warehouse.yaml"
MAPS = {"willow": WILLOW, "tb3": TB3_MAP, "levine": LEVINE, "warehouse": WAREHOUSE}
BOWL = FIXTURES / "images/heightmap_png_bowl/heightmap_bowl.png"
VALLEY = FIXTURES / "images/heightmap_png_winding_valley/heightmap.png"
IMAGES = {"bowl_rgb": BOWL, "winding_valley": VALLEY}

# --- DEMs (fixtures/terrain) ---------------------------------------------------------------------

TERRAIN = FIXTURES / "terrain"
SFBAY = TERRAIN / "dem_sfbay_squared_geotiff/dem_squared.tif"
MOON = TERRAIN / "dem_moon_polar_geotiff/dem_moon.tif"


class DemFacts(TypedDict):
    side: int
    world_width: float
    world_height: float
    min: float
    max: float
    corners: dict[tuple[int, int], float]


#: gz-common Dem_TEST.cc, dem_squared.tif (the oracle quoted in its SOURCE.txt).
GZ_SFBAY: DemFacts = {
    "side": 129,
    "world_width": 3139.7456,
    "world_height": 3984.4849,
    "min": 65.3583,
    "max": 318.441,
    # Elevation(x, y): x = column, y = row from the top (north).
    "corners": {(0, 0): 215.82324, (128, 0): 216.04961, (0, 128): 142.2274, (128, 128): 209.14784},
}

# --- OctoMap files (fixtures/octomap) and CARMEN logs (fixtures/logs) ----------------------------

GEB079 = FIXTURES / "octomap/geb079.bt"
FR079 = FIXTURES / "octomap/scan.dat.bz2"
MIT_DIR = FIXTURES / "logs/raw_carmen_mit_csail"
MIT = MIT_DIR / "mit-csail.clf.bz2"
