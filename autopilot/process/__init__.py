"""autopilot/process"""
