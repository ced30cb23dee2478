"""The network lab: hosts on one machine as network namespaces, joined by veth links that can be
lossy, slow or drop multicast, and what each host puts on the wire. Not part of ./ft; it serves
`./ft bench two_hosts` and tests/workspace/test_two_hosts.py, and any run that wants hosts and a
link (for example a Dask cluster across namespaces).

    netlab/netns.py         hosts (Host), the link between two of them (TwoHosts) or N of them on
                            one switch (Star: cut, kill, plug a host), its Impairment: loss, delay,
                            no multicast (ROS-free: standard library and iproute2; root)
    netlab/rtps_sniff.py    what a host sends: RTPS submessages, retransmissions (ROS-free)
    netlab/two_hosts.py     the force tester's live graph across the two hosts (uses ft_cli.graph)
"""
