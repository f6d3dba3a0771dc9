"""autopilot/mavlink"""
