"""autopilot/estimation"""
