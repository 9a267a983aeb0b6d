#!/usr/bin/env python3
"""Saves the localizer's map after pose_graph_backend's last optimisation.

At the end of a mapping run with the backend (launch/backend.launch): asks the backend to
optimise what it has and to publish the keyframes' optimised poses (~save_trajectory, which also
writes its trajectory when --trajectory is given), waits until the localizer has applied that
keyframe_poses message (its get_info reports the newest one applied), then calls the localizer's
~save_map. The map file then holds every keyframe at its optimised pose, in the backend's map
frame. Exit 0 on success, 1 when a call fails or the poses do not arrive within --timeout.

Usage: save_optimised_map.py MAP_PATH [--trajectory CSV] [--backend /backend]
                             [--localizer /localizer] [--timeout 30]
"""
import argparse
import sys
import time

import rospy
from ground_texture_bow.srv import GetInfo, SaveMap, SaveTrajectory


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("map", help="absolute path of the map file to write")
    ap.add_argument("--trajectory", default="", help="also write the backend's trajectory here")
    ap.add_argument("--backend", default="/backend")
    ap.add_argument("--localizer", default="/localizer")
    ap.add_argument("--timeout", type=float, default=30.0, help="seconds to wait for the poses")
    a = ap.parse_args(rospy.myargv()[1:])
    rospy.init_node("save_optimised_map", anonymous=True, disable_signals=True)
    try:
        for name in (a.backend + "/save_trajectory", a.localizer + "/get_info",
                     a.localizer + "/save_map"):
            rospy.wait_for_service(name, timeout=a.timeout)
        save_traj = rospy.ServiceProxy(a.backend + "/save_trajectory", SaveTrajectory)
        info = rospy.ServiceProxy(a.localizer + "/get_info", GetInfo)
        save_map = rospy.ServiceProxy(a.localizer + "/save_map", SaveMap)
        r = save_traj(path=a.trajectory)
        if r.status.code != 0:
            print("save_optimised_map: the backend: " + r.status.message)
            return 1
        stamp = r.keyframe_poses_stamp
        print("save_optimised_map: backend optimised (%d nodes, %d closures accepted, %d of %d "
              "fixes)%s" % (r.nodes, r.closures_accepted, r.fixes_accepted, r.fixes_received,
                            "" if stamp.is_zero() else "; keyframe poses published"))
        if not r.anchored:
            print("save_optimised_map: the backend never placed this session in the earlier "
                  "map (no two agreeing fixes): nothing to save")
            return 1
        if not r.anchored_at.is_zero():
            print("anchored_at: %.9f" % r.anchored_at.to_sec())
        if not stamp.is_zero():
            deadline = time.time() + a.timeout
            while True:
                got = info().keyframe_poses_stamp
                if got >= stamp:
                    break
                if time.time() > deadline:
                    print("save_optimised_map: the localizer did not apply the backend's keyframe "
                          "poses within %g s (is its keyframe_poses connected? "
                          "launch/backend.launch wires it)" % a.timeout)
                    return 1
                time.sleep(0.05)
        i = info()
        r = save_map(path=a.map)
        print("save_optimised_map: " + r.status.message + " (pose frame %s%s, %d keyframe poses "
              "taken from the backend)" % (i.pose_frame, ", optimised" if i.poses_optimised
                                           else "", i.keyframes_reposed))
        return 0 if r.status.code == 0 else 1
    except (rospy.ROSException, rospy.ServiceException) as e:
        print("save_optimised_map: " + str(e))
        return 1


if __name__ == "__main__":
    sys.exit(main())
