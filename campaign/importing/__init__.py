"""``campaign import``: measured files (CSV, ASCII, MATLAB, Parquet) and a channel map into logs."""
