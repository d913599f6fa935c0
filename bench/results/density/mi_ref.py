import mitsuba as mi, numpy as np, time, sys
mi.set_variant('scalar_rgb')
t=time.time()
sc=mi.load_file(sys.argv[1])
img=mi.render(sc, spp=int(sys.argv[3]))
mi.util.write_bitmap(sys.argv[2], img)
print('done', time.time()-t)
