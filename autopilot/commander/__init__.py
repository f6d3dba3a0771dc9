"""autopilot/commander"""
