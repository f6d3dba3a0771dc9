"""The vehicle flown by the clients users have (MAVSDK, MAVProxy, pymavlink) against
the real processes."""
