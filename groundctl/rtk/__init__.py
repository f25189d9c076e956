"""RTK corrections: RTCM3 sources, framing, GPS_RTCM_DATA fragmentation and forwarding."""
