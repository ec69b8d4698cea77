"""Exudyn's classic planar slider–crank (``Examples/SliderCrank.py`` of Exudyn) with the data of
issue 7: crank 0.3 m, 1 kg, J = m r²/12; rod 1.0 m, 2 kg, J = m L²/12; slider 0.5 kg on
y = 0; gravity 9.81 m/s² in −y; no drive; all links on the x-axis at t = 0 with crank
speed 2π rad/s; 1 s. Rigid bodies ``RigidBody2D``, the slider a ``MassPoint2D``, pins
``RevoluteJoint2D`` (the crank's pivot to ground), the guide a ``CoordinateConstraint``
on the slider's y; Exudyn's default solver (generalized-α, index 3, its default spectral
radius), fixed step ``t_end / steps``.
"""

from __future__ import annotations

import numpy as np

DATA = dict(r=0.3, mc=1.0, L=1.0, mr=2.0, ms=0.5, g=9.81, omega0=2 * np.pi, t_end=1.0)


def build(steps, sensors=False):
    import exudyn as exu
    from exudyn.itemInterface import (CoordinateConstraint, LoadMassProportional, MarkerBodyMass, MarkerBodyPosition,
                                      MarkerBodyRigid, MarkerNodeCoordinate, MassPoint2D, NodePointGround,
                                      ObjectGround, Point2D, RevoluteJoint2D, RigidBody2D, Rigid2D, SensorNode)
    d = DATA
    r, L, w0 = d["r"], d["L"], d["omega0"]
    SC = exu.SystemContainer()
    mbs = SC.AddSystem()
    ground = mbs.AddObject(ObjectGround(referencePosition=[0, 0, 0]))
    ground_node = mbs.AddNode(NodePointGround(referenceCoordinates=[0, 0, 0]))
    # crank: centre at (r/2, 0), rotating about the origin with ω0
    n_crank = mbs.AddNode(Rigid2D(referenceCoordinates=[r / 2, 0, 0], initialVelocities=[0, r / 2 * w0, w0]))
    o_crank = mbs.AddObject(RigidBody2D(physicsMass=d["mc"], physicsInertia=d["mc"] * r**2 / 12, nodeNumber=n_crank))
    # rod: centre at (r + L/2, 0); left end moves with the crank pin (0, r ω0), right end on the guide (v = 0)
    n_rod = mbs.AddNode(Rigid2D(referenceCoordinates=[r + L / 2, 0, 0],
                                initialVelocities=[0, r * w0 / 2, -r * w0 / L]))
    o_rod = mbs.AddObject(RigidBody2D(physicsMass=d["mr"], physicsInertia=d["mr"] * L**2 / 12, nodeNumber=n_rod))
    n_sl = mbs.AddNode(Point2D(referenceCoordinates=[r + L, 0], initialVelocities=[0, 0]))
    o_sl = mbs.AddObject(MassPoint2D(physicsMass=d["ms"], nodeNumber=n_sl))
    m_c0 = mbs.AddMarker(MarkerBodyRigid(bodyNumber=o_crank, localPosition=[-r / 2, 0, 0]))
    m_c1 = mbs.AddMarker(MarkerBodyPosition(bodyNumber=o_crank, localPosition=[r / 2, 0, 0]))
    m_r0 = mbs.AddMarker(MarkerBodyPosition(bodyNumber=o_rod, localPosition=[-L / 2, 0, 0]))
    m_r1 = mbs.AddMarker(MarkerBodyPosition(bodyNumber=o_rod, localPosition=[L / 2, 0, 0]))
    m_sl = mbs.AddMarker(MarkerBodyPosition(bodyNumber=o_sl, localPosition=[0, 0, 0]))
    m_g = mbs.AddMarker(MarkerBodyPosition(bodyNumber=ground, localPosition=[0, 0, 0]))
    mbs.AddObject(RevoluteJoint2D(markerNumbers=[m_g, m_c0]))
    mbs.AddObject(RevoluteJoint2D(markerNumbers=[m_c1, m_r0]))
    mbs.AddObject(RevoluteJoint2D(markerNumbers=[m_r1, m_sl]))
    m_gc = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=ground_node, coordinate=0))
    m_sy = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=n_sl, coordinate=1))
    mbs.AddObject(CoordinateConstraint(markerNumbers=[m_gc, m_sy]))
    for body in (o_crank, o_rod, o_sl):
        mbs.AddLoad(LoadMassProportional(markerNumber=mbs.AddMarker(MarkerBodyMass(bodyNumber=body)),
                                         loadVector=[0, -d["g"], 0]))
    sens = {}
    if sensors:
        for name, node in (("crank", n_crank), ("rod", n_rod)):
            sens[name + "_c"] = mbs.AddSensor(SensorNode(nodeNumber=node, storeInternal=True,
                                                         outputVariableType=exu.OutputVariableType.Coordinates))
            sens[name + "_v"] = mbs.AddSensor(SensorNode(nodeNumber=node, storeInternal=True,
                                                         outputVariableType=exu.OutputVariableType.Coordinates_t))
        sens["slider_c"] = mbs.AddSensor(SensorNode(nodeNumber=n_sl, storeInternal=True,
                                                    outputVariableType=exu.OutputVariableType.Coordinates))
        sens["slider_v"] = mbs.AddSensor(SensorNode(nodeNumber=n_sl, storeInternal=True,
                                                    outputVariableType=exu.OutputVariableType.Coordinates_t))
    mbs.Assemble()
    s = exu.SimulationSettings()
    s.timeIntegration.numberOfSteps = int(steps)
    s.timeIntegration.endTime = d["t_end"]
    s.timeIntegration.verboseMode = 0
    s.solutionSettings.writeSolutionToFile = False
    s.solutionSettings.sensorsWritePeriod = d["t_end"] / steps
    s.displayStatistics = False
    s.displayComputationTime = False
    return exu, SC, mbs, s, dict(crank=n_crank, rod=n_rod, slider=n_sl), sens


def solve(steps):
    """One run; returns x_slider(t_end)."""
    exu, SC, mbs, settings, nodes, _ = build(steps)
    exu.SolveDynamic(mbs, settings)
    return float(mbs.GetNodeOutput(nodes["slider"], exu.OutputVariableType.Position)[0])


def energy_history(steps):
    """(t, x_slider, energy) at every step from stored sensors (reference and current
    coordinates: Exudyn's rigid-body node coordinates are displacements from the reference)."""
    exu, SC, mbs, settings, nodes, sens = build(steps, sensors=True)
    exu.SolveDynamic(mbs, settings)
    d = DATA
    r, L = d["r"], d["L"]
    get = {k: mbs.GetSensorStoredData(v) for k, v in sens.items()}
    t = get["crank_c"][:, 0]
    yc = get["crank_c"][:, 2]           # displacement of the crank centre, reference y = 0
    yr = get["rod_c"][:, 2]
    vc, vr, vs = get["crank_v"][:, 1:], get["rod_v"][:, 1:], get["slider_v"][:, 1:]
    T = (0.5 * d["mc"] * (vc[:, 0]**2 + vc[:, 1]**2) + 0.5 * d["mc"] * r**2 / 12 * vc[:, 2]**2
         + 0.5 * d["mr"] * (vr[:, 0]**2 + vr[:, 1]**2) + 0.5 * d["mr"] * L**2 / 12 * vr[:, 2]**2
         + 0.5 * d["ms"] * (vs[:, 0]**2 + vs[:, 1]**2))
    V = d["g"] * (d["mc"] * yc + d["mr"] * yr)
    xs = r + L + get["slider_c"][:, 1]
    return t, xs, T + V
