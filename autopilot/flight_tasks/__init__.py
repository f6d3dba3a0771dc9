"""autopilot/flight_tasks"""
