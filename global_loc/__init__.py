"""global_loc: where am I in this known map? Global localization from one laser scan.

core/ needs no ROS (maps, scans, matchers, the Localizer); io/ reads messages, recordings and
logs without ROS; offline/ is the command line; ros/ holds the nodes; sim/ the pybullet
simulator and synthetic scans; bench/ the benchmark; testing/ the harnesses of the tests."""
