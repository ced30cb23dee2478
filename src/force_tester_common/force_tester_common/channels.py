"""The force tester's channels and where they travel (pure Python: no ROS import, usable by every core).

Channel names are the DAQ export's column names, SI units. Each sample-block message type carries some
of them, field by field; ``BLOCK_TYPES`` maps type -> (default topic, {message field: channel}).
"""

REQUIRED_CHANNELS = ('time_s', 'encoder_position_m', 'accel_axial_m_s2', 'force_moving_n', 'force_stationary_n')
OPTIONAL_CHANNELS = ('motor_current_a', 'motor_voltage_v', 'motor_velocity_cmd_m_s', 'accel_lateral_m_s2',
                     'accel_vertical_m_s2')
CHANNELS = REQUIRED_CHANNELS + OPTIONAL_CHANNELS

BLOCK_TYPES = {
    'force_tester_msgs/msg/MotorBlock': ('/motor', {'current_a': 'motor_current_a', 'voltage_v': 'motor_voltage_v',
                                                    'velocity_cmd_m_s': 'motor_velocity_cmd_m_s'}),
    'force_tester_msgs/msg/EncoderBlock': ('/encoder', {'position_m': 'encoder_position_m'}),
    'force_tester_msgs/msg/AccelBlock': ('/accel', {'axial_m_s2': 'accel_axial_m_s2',
                                                    'lateral_m_s2': 'accel_lateral_m_s2',
                                                    'vertical_m_s2': 'accel_vertical_m_s2'}),
    'force_tester_msgs/msg/ForceBlock': ('/force', {'moving_n': 'force_moving_n',
                                                    'stationary_n': 'force_stationary_n'}),
}
CORRECTED_TYPE = ('force_tester_msgs/msg/CorrectedForceBlock',
                  ('/force_corrected', {'raw_n': 'raw_n', 'inertial_n': 'inertial_n', 'corrected_n': 'corrected_n',
                                        'filtered_n': 'filtered_n'}))
PULL_EVENT_TYPE = 'force_tester_msgs/msg/PullEvent'
