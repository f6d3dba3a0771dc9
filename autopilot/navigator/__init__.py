"""autopilot/navigator"""
