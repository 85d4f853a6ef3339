"""The simulated closed loop (Flacco 2014 §5, 2015 §VIII): the runtime fed by the simulator,
with a simulated robot that obeys its reaction (R13-R15, R27, R29).

``loop.py`` the cycle (camera frames in, the monitor's reaction, SNS, the robot moves);
``camera_pipeline.py`` frames from capture to delivery; ``loop_truth.py`` its ground truth;
``scenarios.py`` the scripted obstacles and the summary; ``trajectory.py`` the hexagon task;
``report.py`` plots.
"""
