cd /work/main
export ROS_DOMAIN_ID=177 ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
timeout -s INT 25 scripts/in_env.sh python -c "
import cProfile,pstats,sys,signal
from flaair_common.container import main
sys.argv=['container','flaair_sim.plant_node:PlantNode','flaair_sensors.frontend_node:FrontendNode','flaair_control.dsa_controller_node:DsaControllerNode','--ros-args','--params-file','/tmp/prof/params.yaml']
pr=cProfile.Profile(); pr.enable()
try:
    main(sys.argv[1:])
except BaseException as e: print('exc',type(e))
pr.disable(); pr.dump_stats('/tmp/prof/out.prof')
"
