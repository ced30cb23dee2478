"""The force tester's channels, topics and pull events (pure Python: no ROS import).

Channel names are the DAQ export's column names, SI units. Each sample-block message type carries
some of them, field by field; ``BLOCK_TYPES`` maps type -> (default topic, {message field: channel}).
"""

REQUIRED_CHANNELS = ('time_s', 'encoder_position_m', 'accel_axial_m_s2', 'force_moving_n', 'force_stationary_n')
OPTIONAL_CHANNELS = ('motor_current_a', 'motor_voltage_v', 'motor_velocity_cmd_m_s', 'accel_lateral_m_s2',
                     'accel_vertical_m_s2')
CHANNELS = REQUIRED_CHANNELS + OPTIONAL_CHANNELS
#: What the correction cannot do without: the moving cell and the carriage acceleration (m*a), on a time base.
CORE_CHANNELS = ('time_s', 'accel_axial_m_s2', 'force_moving_n')
#: Required channels a campaign may name as absent (campaign.yaml ``absent:``, a channel map's ``absent``):
#: another lab's rig may have no stationary reference cell and no encoder.
ABSENTABLE_CHANNELS = tuple(c for c in REQUIRED_CHANNELS if c not in CORE_CHANNELS)

MOTOR_TYPE = 'force_tester_msgs/msg/MotorBlock'
ENCODER_TYPE = 'force_tester_msgs/msg/EncoderBlock'
ACCEL_TYPE = 'force_tester_msgs/msg/AccelBlock'
FORCE_TYPE = 'force_tester_msgs/msg/ForceBlock'

BLOCK_TYPES = {
    MOTOR_TYPE: ('/motor', {'current_a': 'motor_current_a', 'voltage_v': 'motor_voltage_v',
                            'velocity_cmd_m_s': 'motor_velocity_cmd_m_s'}),
    ENCODER_TYPE: ('/encoder', {'position_m': 'encoder_position_m'}),
    ACCEL_TYPE: ('/accel', {'axial_m_s2': 'accel_axial_m_s2', 'lateral_m_s2': 'accel_lateral_m_s2',
                            'vertical_m_s2': 'accel_vertical_m_s2'}),
    FORCE_TYPE: ('/force', {'moving_n': 'force_moving_n', 'stationary_n': 'force_stationary_n'}),
}
FORCE_FIELDS = tuple(BLOCK_TYPES[FORCE_TYPE][1])
ACCEL_FIELDS = tuple(BLOCK_TYPES[ACCEL_TYPE][1])

CORRECTED_NAME = 'force_tester_msgs/msg/CorrectedForceBlock'
CORRECTED_FIELDS = ('raw_n', 'inertial_n', 'corrected_n', 'filtered_n')
CORRECTED_TYPE = (CORRECTED_NAME, ('/force_corrected', {f: f for f in CORRECTED_FIELDS}))

PULL_EVENT_TYPE = 'force_tester_msgs/msg/PullEvent'
PULL_EVENT_TOPIC = '/pull_event'
# PullEvent.msg's constants (a test checks they match the message definition)
PULL_START = 0
PULL_END = 1

PULL_SCORE_TYPE = 'force_tester_msgs/msg/PullScore'
PULL_SCORE_TOPIC = '/pull_score'          # every score, latched: the history (the last SCORE_QOS depth)
PULL_SCORE_LATEST_TOPIC = '/pull_score_latest'   # the newest score only, latched (depth 1): for late joiners
SET_SUMMARY_TYPE = 'force_tester_msgs/msg/SetSummary'
SET_SUMMARY_TOPIC = '/set_summary'
DIAGNOSTICS_TOPIC = '/diagnostics'

#: every topic of the live graph but /diagnostics (what the recorder records by default)
GRAPH_TOPICS = (*(topic for topic, _fields in BLOCK_TYPES.values()), PULL_EVENT_TOPIC,
                CORRECTED_TYPE[1][0], PULL_SCORE_TOPIC, SET_SUMMARY_TOPIC)

# The monitor's derived topics (force_tester_monitor; display units lbf, see the .msg files)
MONITOR_FORCE_TYPE = 'force_tester_msgs/msg/MonitorForce'
MONITOR_FORCE_TOPIC = '/monitor/force'
PULL_TRACE_TYPE = 'force_tester_msgs/msg/PullTrace'
PULL_TRACE_TOPIC = '/monitor/pull_trace'
MONITOR_SCORE_TYPE = 'force_tester_msgs/msg/MonitorScore'
MONITOR_SCORE_TOPIC = '/monitor/pull_score'
SCORE_HISTORY_TYPE = 'force_tester_msgs/msg/ScoreHistory'
SCORE_HISTORY_TOPIC = '/monitor/score_history'
MONITOR_HEALTH_TYPE = 'force_tester_msgs/msg/MonitorHealth'
MONITOR_HEALTH_TOPIC = '/monitor/health'
#: the Nodes panel's rows: a diagnostic_msgs/DiagnosticArray, one short line a node, STALE when silent
MONITOR_NODES_TOPIC = '/monitor/nodes'
